"""CURL learns the toy pixel task: it brings the red square to the frame centre far better than random actions."""

from __future__ import annotations

import pytest
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_ef import CURL
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.learning import random_return


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=38, max_episode_steps=20)


@pytest.mark.slow
def test_curl_learns_to_bring_the_agent_to_the_centre():
    """Reward: minus the agent's distance to the frame centre; 32x32 crops of 38x38 frames (the paper's 84 of 100).
    Random actions earn about -6 per 20-step episode (about 90 s on 2 cores shared with other jobs)."""
    model = CURL(
        "CnnPolicy", toy_env(), crop_size=32, features_dim=32, buffer_size=5000, learning_starts=100, batch_size=32,
        learning_rate=1e-3, ent_coef=0.01, target_update_interval=2, policy_kwargs={"net_arch": [64, 64]}, seed=0,
        device="cpu",
    )  # fmt: skip
    model.learn(1000)
    trained, _ = evaluate_policy(model, Monitor(toy_env()), n_eval_episodes=20)
    baseline = random_return(toy_env(), 20)
    assert baseline < -4.0
    assert trained > baseline + 2.5, (trained, baseline)
