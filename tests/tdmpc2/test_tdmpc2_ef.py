import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.callbacks import CheckpointCallback, EvalCallback
from stable_baselines3.common.monitor import Monitor

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF
from tests.helpers.tdmpc2 import TINY_EF_POLICY, host_loss, tiny_policy


def toy_env(max_episode_steps: int = 20) -> ToyAgentEnv:
    return ToyAgentEnv(size=64, max_episode_steps=max_episode_steps)


def make(algorithm=TDMPC2EF, env=None, **kwargs):
    arguments = {
        "learning_starts": 10,
        "batch_size": 4,
        "buffer_size": 300,
        "seed": 0,
        "policy_kwargs": tiny_policy(algorithm),
    }
    if algorithm is TDMPC2EF:
        arguments.update(ef_horizon=5, babbling_steps=0)
    arguments.update(kwargs)
    return algorithm("CnnPolicy", env if env is not None else toy_env(), **arguments)


def filled_batch(model, steps: int = 40, batch_size: int = 8):
    """Fill the buffer with seed steps only (no training) and sample one batch."""
    learning_starts = model.learning_starts
    model.learning_starts = steps + 1
    model.learn(steps)
    model.learning_starts = learning_starts
    th.manual_seed(0)
    return model.replay_buffer.sample(batch_size)


def test_exposes_the_ef_contract_and_the_paper_defaults():
    model = make(policy_kwargs={**TINY_EF_POLICY, "num_channels": 8})
    assert model.frame_shape == (3, 64, 64)
    assert model.ef is not None and model.ef.feature_dim == 128 and model.ef.agent_dim == 16
    assert model.replay_buffer.horizon == 5
    assert model.gamma == 0.95  # the heuristic for 20-step episodes
    h = model.encode(th.zeros(2, 9, 64, 64, dtype=th.uint8))
    assert h.shape == (2, 128)
    plain = make(TDMPC2)
    assert not hasattr(plain, "ef") and plain.replay_buffer.horizon == 3
    defaults = TDMPC2EF("CnnPolicy", toy_env(), buffer_size=300, _init_setup_model=False)
    assert (defaults.horizon, defaults.ef_horizon, defaults.babbling_steps, defaults.learning_starts) == (
        3,
        10,
        1250,
        None,  # seed steps derived from the episode length at setup (test_tdmpc2_reference.py)
    )
    assert (defaults.learning_rate, defaults.batch_size, defaults.tau, defaults.rho) == (3e-4, 256, 0.01, 0.5)


def test_world_model_loss_decreases_on_a_fixed_batch():
    model = make(learning_rate=1e-3)
    batch = filled_batch(model)
    model.policy.set_training_mode(True)

    def evaluate():
        th.manual_seed(1)
        losses, (_, logs), _, _ = model.losses(batch)
        return host_loss(model, losses).item(), logs["ef_loss"].item()

    host_before, ef_before = evaluate()
    for _ in range(30):
        model._update(batch)
    host_after, ef_after = evaluate()
    assert host_after < 0.8 * host_before
    assert ef_after < 0.8 * ef_before


def test_host_losses_are_identical_with_and_without_ef():
    with_ef, without_ef = make(), make(TDMPC2)
    for a, b in zip(
        with_ef.world_model.state_dict().values(), without_ef.world_model.state_dict().values(), strict=True
    ):
        th.testing.assert_close(a, b, rtol=0, atol=0)
    batch = filled_batch(with_ef)
    results = []
    for model in (with_ef, without_ef):
        model.policy.set_training_mode(True)
        th.manual_seed(5)
        losses, auxiliary, _, _ = model.losses(batch)
        results.append((losses, auxiliary))
    assert results[0][1] is not None and results[1][1] is None
    results = [losses for losses, _ in results]
    for key in ("consistency_loss", "reward_loss", "value_loss"):
        th.testing.assert_close(results[0][key], results[1][key], rtol=0, atol=0)


def test_ef_loss_reaches_the_encoder_but_not_the_heads():
    model = make()
    batch = filled_batch(model)
    model.policy.set_training_mode(True)
    _, (auxiliary_loss, _), _, _ = model.losses(batch)
    auxiliary_loss.backward()  # beta * ef_loss
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.world_model.encoder.parameters())
    assert all(p.grad is None for p in model.world_model.q_heads.parameters())
    assert all(p.grad is None for p in model.world_model.dynamics.parameters())


class ActionRecorder(gym.Wrapper):
    def __init__(self, env):
        super().__init__(env)
        self.actions = []

    def step(self, action):
        self.actions.append(np.array(action))
        return super().step(action)


def test_babbling_comes_first_then_seed_actions_then_planning():
    env = ActionRecorder(toy_env())
    model = make(env=env, babbling_steps=8, learning_starts=12)
    model.learn(16)
    actions = np.stack(env.actions)
    assert actions.shape == (16, 2)
    assert np.all(np.abs(actions[:8]) == 1.0)
    assert not np.any(np.abs(actions[8:12]) == 1.0)
    assert not np.all(np.abs(actions[12:]) == 1.0)
    assert model.logger.name_to_value["rollout/babbling"] == 0.0  # babbling has ended


def test_save_load_gives_equal_predictions(tmp_path):
    # Episodes of 8 steps: shorter than the default ef_horizon (10), so load must check the saved one (5).
    model = make(env=toy_env(max_episode_steps=8))
    model.learn(16)
    model.save(tmp_path / "model.zip")
    loaded = TDMPC2EF.load(tmp_path / "model.zip", env=toy_env(max_episode_steps=8))
    for a, b in zip(model.policy.state_dict().values(), loaded.policy.state_dict().values(), strict=True):
        th.testing.assert_close(a, b, rtol=0, atol=0)
    assert loaded.gamma == model.gamma and loaded.policy.planner == model.policy.planner
    observation = np.stack([toy_env().reset(seed=3)[0]])
    predictions = []
    for algorithm in (model, loaded):
        th.manual_seed(7)
        predictions.append(algorithm.predict(observation, episode_start=np.ones(1, bool), deterministic=True)[0])
    np.testing.assert_array_equal(predictions[0], predictions[1])


def test_training_is_reproducible_with_a_seed():
    runs = []
    for _ in range(2):
        model = make(seed=3)
        model.learn(16)
        runs.append(model.policy.state_dict())
    for a, b in zip(runs[0].values(), runs[1].values(), strict=True):
        th.testing.assert_close(a, b, rtol=0, atol=0)


def test_predict_warm_start_is_reset_at_episode_start(monkeypatch):
    model = make()
    observation = np.stack([toy_env().reset(seed=0)[0]] * 2)
    _, (plans,) = model.predict(observation)
    state = (np.full_like(plans, 0.5),)
    planner, seen = model.policy.planner, []
    original_plan = planner.plan

    def recording_plan(world_model, z, previous_mean=None, deterministic=False):
        seen.append(previous_mean.clone())
        return original_plan(world_model, z, previous_mean, deterministic)

    monkeypatch.setattr(planner, "plan", recording_plan)
    model.predict(observation, state=state, episode_start=np.array([True, False]))
    assert th.all(seen[0][0] == 0) and th.all(seen[0][1] == 0.5)
    assert np.all(state[0] == 0.5)  # the caller's state is read, not written


def test_learn_on_dmc_reacher_with_callbacks(tmp_path):
    make_env = pytest.importorskip("sb3_ef.envs").make_env
    env = make_env("dmc/reacher-easy", size=64, fast_render=True, episode_length=24)
    eval_env = Monitor(make_env("dmc/reacher-easy", size=64, fast_render=True, episode_length=24))
    try:
        model = make(env=env, babbling_steps=4, learning_starts=8, tensorboard_log=None)
        callbacks = [
            EvalCallback(eval_env, n_eval_episodes=1, eval_freq=12, verbose=0),
            CheckpointCallback(save_freq=12, save_path=str(tmp_path)),
        ]
        model.learn(24, callback=callbacks)
        assert model.num_timesteps == 24
        assert len(model.ep_info_buffer) == 2
        assert list(tmp_path.glob("*.zip"))
    finally:
        env.close()
        eval_env.close()


class VectorObservationEnv(gym.Env):
    observation_space = spaces.Box(-1, 1, (4,), np.float32)
    action_space = spaces.Box(-1, 1, (2,), np.float32)


class DiscreteActionEnv(ToyAgentEnv):
    def __init__(self):
        super().__init__(size=64)
        self.action_space = spaces.Discrete(3)


@pytest.mark.parametrize(
    ("env", "kwargs", "match"),
    [
        (VectorObservationEnv(), {}, "stacked RGB frames"),
        (ToyAgentEnv(size=32), {}, "64x64 frames"),
        (DiscreteActionEnv(), {}, "Box"),
        (toy_env(max_episode_steps=4), {"ef_horizon": 5}, "ef_horizon <= 4"),
        (toy_env(), {"beta": 0.0}, "beta"),
        (toy_env(), {"policy_kwargs": {"horizon": 5}}, "not in policy_kwargs"),
        (toy_env(), {"policy_kwargs": {**TINY_EF_POLICY, "agent_dim": 12}}, "multiple of 8"),
    ],
)
def test_bad_input_is_rejected_at_construction(env, kwargs, match):
    with pytest.raises(ValueError, match=match):
        make(env=env, **kwargs)


def test_gamma_heuristic_needs_a_known_episode_length():
    env = toy_env()
    del env.max_episode_steps
    with pytest.raises(ValueError, match="pass gamma"):
        make(env=env)
    assert make(env=toy_env(), gamma=0.9).gamma == 0.9
