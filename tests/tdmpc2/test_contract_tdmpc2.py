"""SB3's contract on TDMPC2-EF and TD-MPC2: deterministic predictions, the policy saved alone, load with the
constructor's policy_kwargs, channels-last frames."""

import numpy as np
import pytest
import torch as th
from gymnasium import ObservationWrapper, spaces
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

# JSON-like values (lists, not tuples): SB3 stores policy_kwargs as JSON when it can, and compares the loaded ones.
PLAIN_POLICY = {
    "num_channels": 4,
    "mlp_dim": 32,
    "num_q": 2,
    "planner_kwargs": {"iterations": 2, "num_samples": 16, "num_elites": 4, "num_pi_trajs": 2},
}
EF_POLICY = {**PLAIN_POLICY, "agent_dim": 16, "ef_kwargs": {"rollout_hidden_dims": [32], "decoder_channels": 8}}
VARIANTS = {TDMPC2EF: EF_POLICY, TDMPC2: PLAIN_POLICY}


def toy_env(**kwargs) -> ToyAgentEnv:
    return ToyAgentEnv(**{"size": 64, "max_episode_steps": 20, **kwargs})


def make(algorithm=TDMPC2EF, env=None, planner=None, **kwargs):
    policy_kwargs = {**VARIANTS[algorithm]}
    if planner is not None:
        policy_kwargs["planner_kwargs"] = {**policy_kwargs["planner_kwargs"], **planner}
    arguments = {"learning_starts": 10, "batch_size": 4, "buffer_size": 300, "seed": 0, "policy_kwargs": policy_kwargs}
    if algorithm is TDMPC2EF:
        arguments.update(ef_horizon=5, babbling_steps=0)
    return algorithm("CnnPolicy", env if env is not None else toy_env(), **{**arguments, **kwargs})


def observations(n: int = 2) -> np.ndarray:
    return np.stack([toy_env().reset(seed=seed)[0] for seed in range(n)])


def start(n: int = 2) -> np.ndarray:
    return np.ones(n, dtype=bool)


@pytest.mark.parametrize("eval_action", ["elite", "mean"])
def test_deterministic_predict_repeats_and_leaves_the_global_generator(eval_action):
    # A small sampling std keeps the planned actions off the bounds (not all clamped to +-1).
    model = make(planner={"eval_action": eval_action, "max_std": 0.3}).learn(12)
    obs = observations()
    before = th.random.get_rng_state()
    first, _ = model.predict(obs, episode_start=start(), deterministic=True)
    second, _ = model.predict(obs, episode_start=start(), deterministic=True)
    np.testing.assert_array_equal(first, second)
    th.testing.assert_close(th.random.get_rng_state(), before, rtol=0, atol=0)
    # Not a constant: another observation (random pixels, far from the toy frames) gets another plan.
    noise = np.random.default_rng(0).integers(0, 256, size=obs.shape, dtype=np.uint8)
    other, _ = model.predict(noise, episode_start=start(), deterministic=True)
    assert not np.array_equal(first, other)

    # Exploration draws from the global generator, as training does.
    noisy = [model.predict(obs, episode_start=start(), deterministic=False)[0] for _ in range(2)]
    assert not np.array_equal(*noisy)


def test_predict_twice_on_one_observation_gives_one_action():
    # No state hidden in the policy: the same inputs (observation, state, episode_start) give the same action.
    model = make(planner={"max_std": 0.3}).learn(12)
    obs = observations()
    first, first_state = model.predict(obs, deterministic=True)
    second, second_state = model.predict(obs, deterministic=True)
    np.testing.assert_array_equal(first, second)
    np.testing.assert_array_equal(first_state[0], second_state[0])
    warm, _ = model.predict(obs, state=first_state, deterministic=True)
    np.testing.assert_array_equal(model.predict(obs, state=first_state, deterministic=True)[0], warm)


def test_the_state_is_the_warm_start_plan():
    # Gaussian samples only (no policy-prior trajectory), so that the warm start moves every sample.
    model = make(planner={"max_std": 0.3, "num_pi_trajs": 0}).learn(12)
    obs = observations()
    fresh, (plans,) = model.predict(obs, deterministic=True)
    assert plans.shape == (2, model.horizon, 2) and plans.dtype == np.float32
    warm, _ = model.predict(obs, state=(plans,), deterministic=True)
    assert not np.array_equal(warm, fresh)
    restarted, _ = model.predict(obs, state=(plans,), episode_start=start(), deterministic=True)
    np.testing.assert_array_equal(restarted, fresh)
    # One env restarting: its action is the fresh one, the other keeps its warm start.
    mixed, _ = model.predict(obs, state=(plans,), episode_start=np.array([True, False]), deterministic=True)
    np.testing.assert_array_equal(mixed, [fresh[0], warm[1]])
    single, (single_plans,) = model.predict(obs[0], deterministic=True)  # one unbatched observation
    assert single.shape == (2,) and single_plans.shape == (1, model.horizon, 2)


@pytest.mark.parametrize(
    ("state", "episode_start", "match"),
    [
        ((np.zeros((3, 3, 2), np.float32),), None, r"plans of shape \(2, 3, 2\).*got \[\(3, 3, 2\)\]"),
        (np.zeros((2, 3, 2), np.float32), None, "got ndarray"),
        ((np.zeros((2, 3, 2), np.float32),), np.ones(3, bool), r"one episode_start flag per env \(2\), got 3"),
    ],
)
def test_a_state_of_other_envs_is_refused(state, episode_start, match):
    model = make()
    with pytest.raises(ValueError, match=match):
        model.predict(observations(), state=state, episode_start=episode_start)


def test_deterministic_predict_is_the_same_after_save_load(tmp_path):
    model = make().learn(12)
    model.save(tmp_path / "model.zip")
    loaded = TDMPC2EF.load(tmp_path / "model.zip", env=toy_env())
    obs = observations()
    state = loaded_state = None
    for _ in range(2):  # the second call warm-starts from the first call's plans, in both models alike
        expected, state = model.predict(obs, state=state, deterministic=True)
        actions, loaded_state = loaded.predict(obs, state=loaded_state, deterministic=True)
        np.testing.assert_array_equal(actions, expected)
        np.testing.assert_array_equal(loaded_state[0], state[0])


def test_evaluate_policy_is_repeatable():
    model = make().learn(12)
    runs = []
    for _ in range(2):
        env = DummyVecEnv([lambda: Monitor(toy_env(max_episode_steps=8))])
        env.seed(3)
        runs.append(evaluate_policy(model, env, n_eval_episodes=2, deterministic=True, return_episode_rewards=True)[0])
        th.rand(10)  # whatever else draws from the global generator in between
    assert runs[0] == runs[1]


@pytest.mark.parametrize("algorithm", VARIANTS)
def test_policy_saved_alone_predicts_as_the_model(algorithm, tmp_path):
    model = make(algorithm).learn(12)
    model.policy.save(tmp_path / "policy.pt")
    loaded = type(model.policy).load(tmp_path / "policy.pt")
    saved = model.policy.state_dict()
    assert loaded.state_dict().keys() == saved.keys()  # the auxiliary module's weights too
    for name, value in saved.items():
        th.testing.assert_close(loaded.state_dict()[name], value, rtol=0, atol=0)
    assert loaded.planner == model.policy.planner
    expected, _ = model.predict(observations(), episode_start=start(), deterministic=True)
    actions, _ = loaded.predict(observations(), episode_start=start(), deterministic=True)
    np.testing.assert_array_equal(actions, expected)


@pytest.mark.parametrize("algorithm", VARIANTS)
def test_load_with_the_constructors_policy_kwargs(algorithm, tmp_path):
    model = make(algorithm)
    assert model.policy_kwargs == VARIANTS[algorithm]  # horizon, gamma and ef_horizon go to the policy only
    assert (model.policy.planner.horizon, model.policy.planner.gamma) == (model.horizon, model.gamma)
    model.save(tmp_path / "model.zip")
    loaded = algorithm.load(tmp_path / "model.zip", env=toy_env(), policy_kwargs=dict(VARIANTS[algorithm]))
    assert loaded.policy.planner == model.policy.planner
    assert hasattr(loaded, "ef") == (algorithm is TDMPC2EF)


class ChannelsLast(ObservationWrapper):
    """The toy env's frames as (height, width, 3 * frame_stack), the usual layout of image envs."""

    def __init__(self, env: ToyAgentEnv):
        super().__init__(env)
        channels, height, width = env.observation_space.shape
        self.observation_space = spaces.Box(0, 255, (height, width, channels), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation.transpose(1, 2, 0)


def test_channels_last_frames_are_transposed_as_sb3_does():
    env = ChannelsLast(toy_env(frame_stack=1))  # 64x64x3
    model = make(env=env).learn(12)
    assert model.observation_space.shape == (3, 64, 64)
    action, _ = model.predict(env.reset(seed=0)[0], episode_start=start(1), deterministic=True)
    assert action.shape == (2,)
