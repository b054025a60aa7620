"""DrQv2EF on a real pixel env (DMC cartpole through sb3_ef.envs), kept tiny."""

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_ef.drqv2 import DrQv2EF
from sb3_ef.envs import make_env
from tests.helpers.drqv2 import TINY_POLICY


@pytest.fixture
def cartpole():
    env = make_env("dmc/cartpole-swingup", size=64, fast_render=True, seed=0)
    yield env
    env.close()


def tiny_model(env: gym.Env, **kwargs) -> DrQv2EF:
    return DrQv2EF(
        "CnnPolicy",
        env,
        buffer_size=500,
        batch_size=8,
        learning_starts=20,
        babbling_steps=10,
        ef_horizon=3,
        policy_kwargs=TINY_POLICY,
        seed=0,
        **kwargs,
    )


def test_trains_on_dmc_cartpole_at_64(cartpole):
    model = tiny_model(cartpole)
    assert model.frame_shape == (3, 64, 64) and model.ef.decoder.frame_shape == (3, 64, 64)
    model.learn(30)
    logged = model.logger.name_to_value
    # 10 steps after learning_starts, one update every train_freq=2 steps.
    assert model._n_updates == 5 and np.isfinite(logged["train/ef_loss"]) and np.isfinite(logged["train/critic_loss"])


def test_horizon_is_checked_against_the_dmc_episode_length():
    env = make_env("dmc/cartpole-swingup", size=64, fast_render=True, episode_length=10)  # 5 agent steps
    try:
        with pytest.raises(ValueError, match="expected ef_horizon <= 5, got 6"):
            DrQv2EF("CnnPolicy", env, buffer_size=100, ef_horizon=6, policy_kwargs=TINY_POLICY)
    finally:
        env.close()


class NaNRewardAfter(gym.RewardWrapper):
    """A faulty reward wrapper, as users write them: NaN from step ``after`` on."""

    def __init__(self, env: gym.Env, after: int):
        super().__init__(env)
        self.after, self.steps = after, 0

    def reward(self, reward: float) -> float:
        self.steps += 1
        return float("nan") if self.steps > self.after else reward


def test_nan_reward_from_a_real_env_is_refused_before_any_weight_changes(cartpole):
    model = tiny_model(NaNRewardAfter(cartpole, after=25), check_finite_losses=True)
    with pytest.raises(ValueError, match="finite rewards, got nan for env 0 at step 25"):
        model.learn(40)
    # The steps before the faulty one are kept, and nothing non-finite reached the weights.
    assert model.replay_buffer.size() > 0
    assert all(th.isfinite(param).all() for param in model.policy.parameters())
