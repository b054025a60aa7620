"""Action selection of algorithms that explore their own way, and the hook motor babbling takes actions over by."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.policies import BasePolicy


class OwnExplorationMixin:
    """For an SB3 ``OffPolicyAlgorithm``: random actions until ``learning_starts``, then :meth:`_exploration_action`."""

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


#: ``predict``'s observation, its recurrent state (TD-MPC2's warm-start plans) and its answer; ``_sample_action``.
Observation = np.ndarray | dict[str, np.ndarray]
PredictState = tuple[np.ndarray, ...] | None
Prediction = tuple[np.ndarray, PredictState]
SampleAction = Callable[[int, ActionNoise | None, int], tuple[np.ndarray, np.ndarray]]


class ActionOverride(Protocol):
    """What takes over a host's actions for a while (motor babbling); ``None`` leaves the choice to the algorithm."""

    def rollout_action(self, n_envs: int) -> np.ndarray | None:
        """The buffer actions (in [-1, 1], one row per env) of the next rollout step."""

    def evaluation_action(self, observation: Observation, state: PredictState) -> Prediction | None:
        """``predict``'s answer for ``observation`` (env actions and state)."""


def overridden_sample_action(
    override: ActionOverride | None,
    policy: BasePolicy,
    sample: SampleAction,
    learning_starts: int,
    action_noise: ActionNoise | None = None,
    n_envs: int = 1,
) -> tuple[np.ndarray, np.ndarray]:
    """``_sample_action``'s (env, buffer) actions: ``override``'s when it gives some, else ``sample``'s."""
    buffer_action = override.rollout_action(n_envs) if override is not None else None
    if buffer_action is None:
        return sample(learning_starts, action_noise, n_envs)
    return policy.unscale_action(buffer_action), buffer_action


def overridden_predict(
    override: ActionOverride | None,
    predict: Callable[..., Prediction],
    observation: Observation,
    state: PredictState = None,
    episode_start: np.ndarray | None = None,
    deterministic: bool = False,
) -> Prediction:
    """``predict``'s answer, ``override``'s when it gives one (as a partial over the first two: a ``predict``)."""
    answer = override.evaluation_action(observation, state) if override is not None else None
    return predict(observation, state, episode_start, deterministic) if answer is None else answer


class ActionOverrideMixin:
    """Lets an :class:`ActionOverride` (``action_override``, never saved) replace an off-policy algorithm's actions."""

    policy: BasePolicy
    action_override: ActionOverride | None = None

    def _sample_action(self, *args: Any) -> tuple[np.ndarray, np.ndarray]:
        return overridden_sample_action(self.action_override, self.policy, super()._sample_action, *args)  # type: ignore[misc]

    def predict(self, *args: Any, **kwargs: Any) -> Prediction:
        return overridden_predict(self.action_override, super().predict, *args, **kwargs)  # type: ignore[misc]

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "action_override"]  # type: ignore[misc]
