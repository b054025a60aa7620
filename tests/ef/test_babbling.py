"""Motor babbling (sb3_ef.ef.babbling): the callback on every off-policy algorithm, the hosts' short form, the
seeded stream, babbling during evaluation and the argument checks (adaptive babbling: test_babbling_adaptive.py).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium.wrappers import RescaleAction
from sb3_contrib import TQC
from stable_baselines3 import DDPG, PPO, SAC, TD3
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, EvalCallback
from stable_baselines3.common.logger import KVWriter, Logger

from sb3_ef import SACEF, TD3EF, TDMPC2, TDMPC2EF, TQCEF, DrQv2, DrQv2EF, MotorBabblingCallback
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.ef.babbling import babble
from sb3_ef.envs.toy import ToyAgentEnv

EPISODE = 10
LOW, HIGH = -2.0, 3.0  # asymmetric action bounds: the executed action is the stored one unscaled
SB3_POLICY = {
    "net_arch": [16],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 32},
}
EF_HOST = {"ef_horizon": 3, "agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8}}
DRQV2_POLICY = {"net_arch": [16], "trunk_dim": 8, "features_dim": 16, "agent_dim": 4}
EF_KWARGS = {"ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}}
TDMPC2_POLICY = {
    "num_channels": 4, "mlp_dim": 16, "num_q": 2,
    "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 1},
}  # fmt: skip
# Each algorithm's tiny arguments and its frame size (TD-MPC2's encoder needs 64x64).
ALGORITHMS = {
    SAC: ({"policy_kwargs": SB3_POLICY}, 32),
    TD3: ({"policy_kwargs": SB3_POLICY}, 32),
    DDPG: ({"policy_kwargs": SB3_POLICY}, 32),
    TQC: ({"policy_kwargs": SB3_POLICY}, 32),
    SACEF: ({"policy_kwargs": SB3_POLICY, **EF_HOST}, 32),
    TD3EF: ({"policy_kwargs": SB3_POLICY, **EF_HOST}, 32),
    TQCEF: ({"policy_kwargs": SB3_POLICY, **EF_HOST}, 32),
    DrQv2: ({"policy_kwargs": {"net_arch": [8], "trunk_dim": 8}}, 32),
    DrQv2EF: ({"policy_kwargs": {**DRQV2_POLICY, **EF_KWARGS}, "ef_horizon": 3}, 32),
    TDMPC2: ({"policy_kwargs": TDMPC2_POLICY}, 64),
    TDMPC2EF: ({"policy_kwargs": {**TDMPC2_POLICY, "agent_dim": 16, **EF_KWARGS}, "ef_horizon": 3}, 64),
}
EF_HOSTS = (SACEF, TD3EF, TQCEF, DrQv2EF, TDMPC2EF)


class ExecutedActions(gym.Wrapper):
    """Records the actions the env is stepped with."""

    def __init__(self, env: gym.Env):
        super().__init__(env)
        self.actions: list[np.ndarray] = []

    def step(self, action):
        self.actions.append(np.array(action, dtype=np.float32))
        return super().step(action)


class BufferActions(BaseCallback):
    """The buffer action of every rollout step."""

    def __init__(self):
        super().__init__()
        self.actions: list[np.ndarray] = []

    def _on_step(self) -> bool:
        self.actions.append(self.locals["buffer_actions"].copy())
        return True


class RecordingWriter(KVWriter):
    def __init__(self):
        self.records: list[dict] = []

    def write(self, key_values, key_excluded, step=0):
        self.records.append(dict(key_values))


def toy_env(size: int = 32) -> ToyAgentEnv:
    return ToyAgentEnv(size=size, max_episode_steps=EPISODE)


def make(algorithm, env=None, **kwargs):
    arguments, size = ALGORITHMS[algorithm]
    arguments = {"buffer_size": 200, "learning_starts": 8, "batch_size": 4, "seed": 0, **arguments, **kwargs}
    if algorithm in EF_HOSTS:
        arguments.setdefault("babbling_steps", 0)
    arguments["policy_kwargs"] = dict(arguments["policy_kwargs"])  # SB3 writes into the dict it is given
    return algorithm("CnnPolicy", env if env is not None else toy_env(size), **arguments)


def stored_actions(buffer: ReplayBuffer) -> np.ndarray:
    """The actions of the (only) env's replay buffer in step order (the ring has not wrapped), through SB3's
    ``actions`` array, which SequenceReplayBuffer offers too."""
    return np.asarray(buffer.actions[: buffer.size(), 0])


def babbled(model, steps: int, **learn_kwargs) -> np.ndarray:
    recorder = BufferActions()
    callback = learn_kwargs.pop("callback", None)
    model.learn(steps, callback=recorder if callback is None else [callback, recorder], **learn_kwargs)
    return np.concatenate(recorder.actions)


@pytest.mark.parametrize("algorithm", list(ALGORITHMS), ids=lambda algorithm: algorithm.__name__)
def test_the_callback_babbles_on_every_off_policy_algorithm_and_stores_what_was_executed(algorithm):
    size = ALGORITHMS[algorithm][1]
    env = ExecutedActions(RescaleAction(toy_env(size), LOW, HIGH))
    model = make(algorithm, env=env)
    writer = RecordingWriter()
    model.set_logger(Logger(folder=None, output_formats=[writer]))
    babbling = MotorBabblingCallback(2 * EPISODE - 4)
    model.learn(3 * EPISODE, callback=babbling, log_interval=1)

    stored, executed = stored_actions(model.replay_buffer), np.stack(env.actions)
    assert stored.shape == executed.shape == (3 * EPISODE, 2)
    np.testing.assert_allclose(executed, LOW + (stored + 1.0) * (HIGH - LOW) / 2.0, rtol=1e-6, atol=1e-6)
    assert np.all(np.abs(stored[:16]) == 1.0) and not np.all(np.abs(stored[16:]) == 1.0)
    assert [record["rollout/babbling"] for record in writer.records] == [1.0, 0.0, 0.0]  # one record per episode
    assert writer.records[1]["babbling/end_step"] == 16 and writer.records[1]["babbling/end_reason"] == "steps"
    assert (babbling.end_step, babbling.end_reason) == (16, "steps")
    assert "_sample_action" not in vars(model)  # the shadow is gone after training


def test_seeded_babbling_draws_the_first_stream_spawned_from_the_model_seed():
    """The stream sb3-ef hosts have always babbled: generator = default_rng(SeedSequence(seed).spawn(2)[0]), one
    draw of shape (n_envs, action_dim) per step."""
    runs = {seed: babbled(make(DrQv2EF, seed=seed, babbling_steps=10, learning_starts=100), 20) for seed in (3, 4)}
    for seed, actions in runs.items():
        rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[0])
        expected = np.concatenate([babble(rng, (1, 2), "sign") for _ in range(10)])
        np.testing.assert_array_equal(actions[:10], expected)
        assert np.all(np.abs(actions[10:]) < 1)  # uniform warm-up actions after babbling
    assert not np.array_equal(runs[3][:10], runs[4][:10])


@pytest.mark.parametrize("algorithm", [DrQv2EF, TDMPC2EF])
def test_the_constructor_form_is_the_callback(algorithm):
    # Each model is built (seeding the global generators) right before it learns.
    short = make(algorithm, babbling_steps=12, babbling_mode="clamped_uniform")
    actions = [babbled(short, 2 * EPISODE)]
    explicit = make(algorithm, babbling_steps=0)
    actions.append(babbled(explicit, 2 * EPISODE, callback=MotorBabblingCallback(12, "clamped_uniform")))
    np.testing.assert_array_equal(actions[0], actions[1])
    assert short._n_updates == explicit._n_updates > 0
    for (name, a), b in zip(short.policy.state_dict().items(), explicit.policy.state_dict().values(), strict=True):
        assert th.equal(a, b), name


def test_babbling_continues_its_stream_across_save_load(tmp_path):
    straight = babbled(make(DrQv2EF, babbling_steps=30, learning_starts=100), 40)
    model = make(DrQv2EF, babbling_steps=30, learning_starts=100)
    first = babbled(model, 20)
    model.save(tmp_path / "model")
    loaded = DrQv2EF.load(tmp_path / "model", env=toy_env())
    resumed = babbled(loaded, 20, reset_num_timesteps=False)
    np.testing.assert_array_equal(np.concatenate([first, resumed])[:30], straight[:30])
    assert np.all(np.abs(resumed[10:]) < 1)  # babbling stopped at 30 steps in all


def test_a_save_during_training_stores_the_babbling_state_not_the_callback(tmp_path):
    class SaveAtStep5(BaseCallback):
        def _on_step(self) -> bool:
            if self.num_timesteps == 5:
                self.model.save(tmp_path / "during")
            return True

    straight = babbled(make(SAC), 10, callback=MotorBabblingCallback(8))
    make(SAC).learn(10, callback=[MotorBabblingCallback(8), SaveAtStep5()])
    loaded = SAC.load(tmp_path / "during", env=toy_env())
    assert not {"_sample_action", "_excluded_save_params"} & set(vars(loaded))
    assert loaded.num_timesteps == 5 and loaded._motor_babbling.end_step is None  # saved mid-babbling
    resumed = babbled(loaded, 5, callback=MotorBabblingCallback(8), reset_num_timesteps=False)
    np.testing.assert_array_equal(resumed[:3], straight[5:8])


def test_a_new_run_from_step_zero_babbles_again():
    model = make(DrQv2EF, babbling_steps=5, learning_starts=100)
    babbled(model, 10)
    again = babbled(model, 10)
    assert np.all(np.abs(again[:5]) == 1.0) and np.all(np.abs(again[5:]) < 1)


def test_clamped_uniform_babbling_saturates_about_three_quarters():
    actions = babbled(make(DrQv2EF, babbling_steps=400, babbling_mode="clamped_uniform", learning_starts=1000), 400)
    assert np.all(np.abs(actions) <= 1) and 0.7 < np.mean(np.abs(actions) == 1) < 0.8


@pytest.mark.parametrize("in_eval", [False, True])
def test_evaluation_during_training_babbles_only_with_in_eval(in_eval):
    eval_env = ExecutedActions(toy_env())
    model = make(DrQv2EF, babbling_steps=20, babbling_in_eval=in_eval, learning_starts=100)
    evaluation = EvalCallback(eval_env, eval_freq=15, n_eval_episodes=1, verbose=0)
    model.learn(30, callback=evaluation)
    during, after = (np.stack(eval_env.actions[i * EPISODE : (i + 1) * EPISODE]) for i in (0, 1))
    assert np.all(np.abs(during) == 1.0) == in_eval  # the evaluation at step 15, inside babbling
    assert np.all(np.abs(after) < 1)  # the evaluation at step 30: the policy acts
    assert np.all(np.abs(model.predict(toy_env().reset(seed=0)[0])[0]) < 1)  # outside learn, always the policy


def test_two_babbling_callbacks_in_one_learn_are_refused():
    with pytest.raises(ValueError, match="babbling_steps=0 to pass your own"):
        make(DrQv2EF, babbling_steps=5).learn(10, callback=MotorBabblingCallback(5))
    with pytest.raises(ValueError, match="Two MotorBabblingCallbacks"):
        make(SAC).learn(10, callback=CallbackList([MotorBabblingCallback(5), MotorBabblingCallback(5)]))


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        ({"steps": -1}, r"steps must be an int >= 0 or 'adaptive', got -1"),
        ({"steps": "often"}, r"steps must be an int >= 0 or 'adaptive', got 'often'"),
        ({"steps": 10, "mode": "gauss"}, r"mode must be one of \('sign', 'clamped_uniform'\), got 'gauss'"),
        ({"steps": 10, "patience": 3}, r"\['patience'\] apply to steps='adaptive' only"),
        ({"steps": "adaptive", "criterion": float}, r"needs max_steps >= 1 .*got None"),
        ({"steps": "adaptive", "max_steps": 10, "min_steps": 20, "criterion": float}, r"min_steps .*got 20"),
        ({"steps": "adaptive", "max_steps": 10, "patience": 0, "criterion": float}, r"patience must be >= 1, got 0"),
        ({"steps": "adaptive", "max_steps": 10, "min_delta": 1.0, "criterion": float}, r"min_delta .*got 1.0"),
        ({"steps": "adaptive", "max_steps": 10}, r"exactly one of eval_env .* and criterion"),
    ],
)
def test_bad_arguments_are_named_at_construction(arguments, message):
    with pytest.raises(ValueError, match=message):
        MotorBabblingCallback(**arguments)


def test_algorithms_the_callback_cannot_drive_are_named():
    with pytest.raises(TypeError, match=r"needs an off-policy algorithm .*got PPO"):
        PPO("MlpPolicy", "Pendulum-v1", n_steps=16, batch_size=16).learn(16, callback=MotorBabblingCallback(5))
    with pytest.raises(TypeError, match=r"eval_env must be a single gymnasium\.Env"):
        MotorBabblingCallback("adaptive", max_steps=10, eval_env="toy/agent-v0")


def test_a_callback_whose_steps_have_passed_says_it_will_not_babble():
    model = SAC("MlpPolicy", "Pendulum-v1", learning_starts=100, buffer_size=200, seed=0).learn(30)
    with pytest.warns(UserWarning, match=r"will not babble.*starts at step 30.*pass steps=50"):
        model.learn(20, callback=MotorBabblingCallback(20), reset_num_timesteps=False)


def test_hosts_are_taken_over_through_their_hook_not_patched():
    env = ToyAgentEnv(size=32, max_episode_steps=20)
    model = SACEF("CnnPolicy", env, policy_kwargs=SB3_POLICY, buffer_size=100, learning_starts=100, **EF_HOST)
    seen = []

    class Spy(BaseCallback):
        def _on_step(self) -> bool:
            seen.append((self.model.action_override, "_sample_action" in vars(self.model)))
            return True

    model.learn(5, callback=[MotorBabblingCallback(5), Spy()])
    assert all(isinstance(override, MotorBabblingCallback) and not patched for override, patched in seen)
    assert model.action_override is None  # released after learn
