"""Action selection: of algorithms that explore their own way (DrQ-v2's scheduled noise, TD-MPC2's planner), and
the hook through which motor babbling takes the actions over."""

from __future__ import annotations

from typing import Protocol

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy


class OwnExplorationMixin:
    """Mixed into an SB3 ``OffPolicyAlgorithm``: uniform random actions before ``learning_starts``, then the
    algorithm's :meth:`_exploration_action` (SB3's ``action_noise`` is not used)."""

    num_timesteps: int
    action_space: spaces.Space
    policy: BasePolicy

    def _exploration_action(self, n_envs: int) -> np.ndarray:
        """The algorithm's exploration action for each env, scaled to [-1, 1] (the buffer action)."""
        raise NotImplementedError

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.num_timesteps < learning_starts:
            uniform = np.array([self.action_space.sample() for _ in range(n_envs)])
            buffer_action = self.policy.scale_action(uniform)
        else:
            buffer_action = self._exploration_action(n_envs)
        return self.policy.unscale_action(buffer_action), buffer_action


class ActionOverride(Protocol):
    """What takes over a host's actions for a while (motor babbling): each method returns the actions to use, or
    ``None`` to leave the choice to the algorithm."""

    def rollout_action(self, n_envs: int) -> np.ndarray | None:
        """The buffer actions (in [-1, 1], one row per env) of the next rollout step."""

    def evaluation_action(
        self, observation: np.ndarray | dict[str, np.ndarray], state: tuple[np.ndarray, ...] | None
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None] | None:
        """``predict``'s answer for ``observation`` (env actions and state)."""


class ActionOverrideMixin:
    """The hook through which an :class:`ActionOverride` (set as ``action_override``, never saved) replaces the
    rollout actions and ``predict``'s answers of an SB3 off-policy algorithm, mixed in before it."""

    policy: BasePolicy
    action_override: ActionOverride | None = None

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.action_override is not None:
            buffer_action = self.action_override.rollout_action(n_envs)
            if buffer_action is not None:
                return self.policy.unscale_action(buffer_action), buffer_action
        return super()._sample_action(learning_starts, action_noise, n_envs)  # type: ignore[misc]

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        if self.action_override is not None:
            answer = self.action_override.evaluation_action(observation, state)
            if answer is not None:
                return answer
        return super().predict(observation, state, episode_start, deterministic)  # type: ignore[misc]

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "action_override"]  # type: ignore[misc]
