"""Acting with a trained Dreamer-v3: sheeprl's player built from a checkpoint's weights, and evaluation episodes."""

from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.dreamerv3.config import FRAME_KEY


def forked_rng(device: th.device) -> AbstractContextManager[None]:
    """torch's random state (CPU and ``device``) restored at the end of the block."""
    return th.random.fork_rng(devices=[device.index or 0] if device.type == "cuda" else [])


def env_actions(actions: np.ndarray, action_space: gym.spaces.Box, normalize: bool) -> np.ndarray:
    """The actor's actions in the env's bounds, as sheeprl's ``NormalizeAction`` gives them in training."""
    if not normalize:
        return actions.astype(action_space.dtype, copy=False)
    bounded = np.isfinite(action_space.low) & np.isfinite(action_space.high)
    low, high = np.where(bounded, action_space.low, -1), np.where(bounded, action_space.high, 1)
    clipped = np.where(bounded, np.clip(actions, -1, 1), actions)
    return np.where(bounded, (clipped + 1) / 2 * (high - low) + low, clipped).astype(action_space.dtype, copy=False)


def distribution_mode(distribution: th.distributions.Distribution) -> th.Tensor:
    """The mode of a sheeprl action distribution (of a transformed one: its base's mode through the transforms)."""
    inner = distribution
    while isinstance(inner, th.distributions.Independent):
        inner = inner.base_dist
    if isinstance(inner, th.distributions.TransformedDistribution):
        value = distribution_mode(inner.base_dist)
        for transform in inner.transforms:
            value = transform(value)
        return value
    return inner.mode


class Player:
    """sheeprl's Dreamer-v3 player for ``n_envs`` envs with a checkpoint ``state``'s weights, a frame per env a step.

    :param fabric: the Lightning Fabric the models are set up with (its device and precision).
    :param cfg: the run's resolved sheeprl configuration (a ``dotdict``).
    :param frame_shape: ``(3, h, w)``.
    """

    def __init__(
        self,
        fabric: Any,
        cfg: Any,
        frame_shape: tuple[int, int, int],
        action_space: gym.spaces.Box,
        state: dict[str, Any],
        n_envs: int = 1,
    ):
        from sheeprl.algos.dreamer_v3.agent import build_agent

        observation_space = gym.spaces.Dict({FRAME_KEY: gym.spaces.Box(0, 255, frame_shape, np.uint8)})
        weights = (state[key] for key in ("world_model", "actor", "critic", "target_critic"))
        *_, self.player = build_agent(fabric, tuple(action_space.shape), True, cfg, observation_space, *weights)
        self.device, self.frame_shape, self.action_space = fabric.device, frame_shape, action_space
        self.normalize = bool(cfg.algo.get("normalize_actions", False))
        self.action_clip = float(cfg.algo.actor.get("action_clip", 0.0))
        self.player.num_envs = n_envs
        self.player.init_states()

    def reset(self, envs: list[int] | None = None) -> None:
        """Start new episodes in ``envs`` (all by default)."""
        self.player.init_states(envs)

    @th.no_grad()
    def act(self, frames: np.ndarray, greedy: bool) -> np.ndarray:
        """The env actions ``(n_envs, action_dim)`` for the current frames; ``greedy`` takes the policy's mode."""
        n_envs = self.player.num_envs
        if frames.shape[0] != n_envs or frames.shape[1] != FRAME_CHANNELS:
            raise ValueError(f"expected {n_envs} RGB frames of shape (3, h, w), got an array of shape {frames.shape}")
        observation = th.as_tensor(frames, device=self.device).float().view(1, n_envs, *frames.shape[1:]) / 255 - 0.5
        if greedy:
            actions = self._modes({FRAME_KEY: observation})
        else:
            actions = th.cat(self.player.get_actions({FRAME_KEY: observation}, False), -1)
        return env_actions(actions.reshape(n_envs, -1).cpu().numpy(), self.action_space, self.normalize)

    def _modes(self, observation: dict[str, th.Tensor]) -> th.Tensor:
        """sheeprl's acting step with the posterior's and the actor's modes (sheeprl's greedy step samples both)."""
        from sheeprl.algos.dreamer_v2.utils import compute_stochastic_state
        from sheeprl.algos.dreamer_v3.agent import clip_actions

        player, rssm = self.player, self.player.rssm
        embedded = player.encoder(observation)
        player.recurrent_state = rssm.recurrent_model(
            th.cat((player.stochastic_state, player.actions), -1), player.recurrent_state
        )
        posterior_input = embedded if player.decoupled_rssm else th.cat((player.recurrent_state, embedded), -1)
        logits = rssm._uniform_mix(rssm.representation_model(posterior_input))
        posterior = compute_stochastic_state(logits, discrete=rssm.discrete, sample=False)
        player.stochastic_state = posterior.view(*posterior.shape[:-2], -1)
        with forked_rng(self.device):  # the actor's forward pass also draws a sample, which is not used
            _, distributions = player.actor(th.cat((player.stochastic_state, player.recurrent_state), -1), False)
        player.actions = clip_actions(th.cat([distribution_mode(d) for d in distributions], -1), self.action_clip)
        return player.actions

    def recurrent_state(self) -> tuple[np.ndarray, ...]:
        """The per-env recurrent state, stochastic state and previous action (numpy copies)."""
        return tuple(t.detach().cpu().numpy().copy() for t in self._state_tensors())

    def set_recurrent_state(self, state: tuple[np.ndarray, ...]) -> None:
        """Restore a memory given by :meth:`recurrent_state`."""
        current = self._state_tensors()
        if len(state) != len(current) or any(
            np.shape(s) != tuple(t.shape) for s, t in zip(state, current, strict=True)
        ):
            shapes = [tuple(t.shape) for t in current]
            raise ValueError(f"state must be the {len(current)} arrays of shapes {shapes} predict returned")
        self.player.recurrent_state, self.player.stochastic_state, self.player.actions = (
            th.as_tensor(s, device=self.device, dtype=t.dtype) for s, t in zip(state, current, strict=True)
        )

    def _state_tensors(self) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        return self.player.recurrent_state, self.player.stochastic_state, self.player.actions


def run_episodes(
    player: Player, env: gym.Env, n_episodes: int, seed: int, greedy: bool = False
) -> tuple[float, float | None]:
    """Mean return over ``n_episodes`` seeded episodes and the success rate (``None`` without one)."""
    returns, successes = [], []
    with forked_rng(player.device):
        th.manual_seed(seed)
        for episode in range(n_episodes):
            observation, info = env.reset(seed=seed if episode == 0 else None)
            player.reset()
            total, done = 0.0, False
            while not done:
                action = player.act(observation[np.newaxis, -FRAME_CHANNELS:], greedy)[0]
                observation, reward, terminated, truncated, info = env.step(action)
                total += float(reward)
                done = terminated or truncated
            returns.append(total)
            if "is_success" in info:
                successes.append(float(bool(info["is_success"])))
    return float(np.mean(returns)), (float(np.mean(successes)) if successes else None)
