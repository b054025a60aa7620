"""Baselines for the learning tests: what a policy that does not read the image earns."""

from __future__ import annotations

import gymnasium as gym
import numpy as np


def random_return(env: gym.Env, episodes: int) -> float:
    """Mean return of uniform random actions in [-1, 1] over ``episodes`` episodes (episode i reset with seed i)."""
    rng, returns = np.random.default_rng(0), []
    shape = env.action_space.shape
    for episode in range(episodes):
        env.reset(seed=episode)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(rng.uniform(-1, 1, shape))
            total, done = total + float(reward), terminated or truncated
        returns.append(total)
    return float(np.mean(returns))
