"""Dreamer-v3 (sheeprl's) learns the toy pixel task with the CPU-sized entry of zoo_configs/dreamerv3.yml."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sb3_ef.zoo.config import default_config_path, load_config

EPISODES = 10


def mean_return(env: gym.Env, act, seed: int) -> float:
    """Mean return over ``EPISODES`` episodes from resets seeded ``seed``, ``seed + 1``, ...; ``act(observation,
    episode_start)`` gives each action."""
    returns = []
    for episode in range(EPISODES):
        observation, _ = env.reset(seed=seed + episode)
        total, done, start = 0.0, False, True
        while not done:
            observation, reward, terminated, truncated, _ = env.step(act(observation, start))
            total, done, start = total + reward, terminated or truncated, False
        returns.append(total)
    return float(np.mean(returns))


@pytest.mark.slow
def test_dreamer_learns_to_keep_the_toy_agent_near_the_centre(tmp_path):
    # Reward: minus the agent's distance to the centre each step (in frame sizes). Random actions score about -8
    # per 25-step episode (episode returns spread by ~2.7, so ~0.9 for a mean of 10); moving to the centre and
    # staying there scores about -0.5.
    pytest.importorskip("sheeprl")
    from sb3_ef.dreamerv3 import DreamerV3

    entry = load_config(default_config_path("dreamerv3"))["toy/agent-v0"]
    kwargs = {key: value for key, value in entry.items() if key not in ("n_timesteps", "env_kwargs")}
    env = gym.make("toy/agent-v0", **entry["env_kwargs"])
    model = DreamerV3(env=env, work_dir=tmp_path, seed=0, device="cpu", **kwargs)
    model.learn(entry["n_timesteps"])

    eval_env = gym.make("toy/agent-v0", **entry["env_kwargs"])
    memory: dict[str, tuple] = {}

    def dreamer(observation, start):
        action, memory["state"] = model.predict(
            observation, state=None if start else memory["state"], deterministic=True
        )
        return action

    eval_env.action_space.seed(0)
    trained = mean_return(eval_env, dreamer, seed=100)
    baseline = mean_return(eval_env, lambda observation, start: eval_env.action_space.sample(), seed=100)
    assert trained > baseline + 4.0, (trained, baseline)
