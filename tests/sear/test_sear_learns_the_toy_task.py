"""SEAR learns the toy pixel task: it brings the red square to the frame centre far better than random actions."""

from __future__ import annotations

import pytest
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_ef import SEAR
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.learning import random_return


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20, agent_masks=True)


@pytest.mark.slow
def test_sear_learns_to_bring_the_agent_to_the_centre():
    """Reward: minus the agent's distance to the frame centre, so the policy must find the red square in the image.
    Random actions earn about -6 per 20-step episode (about 15 min on 2 cores shared with other jobs)."""
    th.manual_seed(0)
    model = SEAR(
        "CnnPolicy", toy_env(), buffer_size=5000, learning_starts=100, batch_size=32, learning_rate=1e-3,
        train_freq=1, exploration_std="linear(1.0,0.1,600)", policy_kwargs={"features_dim": 128, "net_arch": [64, 64],
        "trunk_dim": 32}, seed=0, device="cpu",
    )  # fmt: skip
    model.learn(1000)
    trained, _ = evaluate_policy(model, Monitor(toy_env()), n_eval_episodes=20)
    baseline = random_return(toy_env(), 20)
    assert baseline < -4.0
    assert trained > baseline + 2.5, (trained, baseline)
