"""Action selection of algorithms that explore their own way (DrQ-v2's scheduled noise, TD-MPC2's planner)."""

from __future__ import annotations

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
