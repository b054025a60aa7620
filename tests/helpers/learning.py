"""For the learning tests: what a policy that does not read the image earns, and babbling windows of the toy world."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

from sb3_ef.envs.toy import ToyAgentEnv


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


def trained_and_random_returns(model: Any, make_env: Callable[[], gym.Env], episodes: int = 20) -> tuple[float, float]:
    """The model's mean deterministic return over ``episodes`` of a fresh env, and :func:`random_return`'s."""
    trained, _ = evaluate_policy(model, Monitor(make_env()), n_eval_episodes=episodes)
    return float(trained), random_return(make_env(), episodes)


def toy_babbling_windows(size: int, episodes: int, seed: int, horizon: int, episode: int) -> dict[str, th.Tensor]:
    """Babble (random +-1 actions) in the toy world for ``episodes`` episodes of ``episode`` steps and cut every full
    EF window out of each: the context ``obs``, the ``horizon`` ``actions`` and future ``frames``, and the ``agent``
    and ``distractor`` masks of steps t .. t + horizon."""
    env = ToyAgentEnv(size=size, max_episode_steps=episode)
    rng = np.random.default_rng(seed)
    windows: dict[str, list[np.ndarray]] = {key: [] for key in ("obs", "actions", "frames", "agent", "distractor")}
    for index in range(episodes):
        obs, _ = env.reset(seed=seed * 1000 + index)
        observations, agent, distractor = [obs], [env.agent_mask()], [env.distractor_mask()]
        actions = np.where(rng.random((episode, 2)) < 0.5, -1.0, 1.0).astype(np.float32)
        for action in actions:
            observations.append(env.step(action)[0])
            agent.append(env.agent_mask())
            distractor.append(env.distractor_mask())
        for t in range(episode - horizon + 1):
            windows["obs"].append(observations[t])
            windows["actions"].append(actions[t : t + horizon])
            windows["frames"].append(np.stack([o[-3:] for o in observations[t + 1 : t + horizon + 1]]))
            windows["agent"].append(np.stack(agent[t : t + horizon + 1]))
            windows["distractor"].append(np.stack(distractor[t : t + horizon + 1]))
    return {key: th.as_tensor(np.stack(values)) for key, values in windows.items()}
