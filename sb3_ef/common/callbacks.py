"""Motor babbling: random +-1 actions at the start of training, through a hook algorithms mix in."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.callbacks import BaseCallback

ActionOverride = Callable[[int], np.ndarray]
BABBLING_MODES = ("sign", "clamped_uniform")


class ActionOverrideMixin:
    """The babbling hook: while ``action_override`` is set, it chooses every rollout action.

    Put the mixin first in the bases (``class MyAlgo(ActionOverrideMixin, OffPolicyAlgorithm)``) and, where the
    algorithm picks its actions (``_sample_action`` for SB3 off-policy algorithms), use
    ``self._override_actions(n_envs)`` when it is not ``None``, for both warm-up and policy actions.
    The override is never saved with the model.
    """

    action_override: ActionOverride | None = None

    def _override_actions(self, n_envs: int) -> np.ndarray | None:
        """Actions (n_envs, action_dim) in [-1, 1] from the hook, or ``None`` when no override is set."""
        if self.action_override is None:
            return None
        actions = np.asarray(self.action_override(n_envs), dtype=np.float32)
        action_space = getattr(self, "action_space", None)
        expected = (n_envs, *action_space.shape) if action_space is not None else (n_envs, *actions.shape[1:])
        if actions.shape != expected:
            raise ValueError(f"action_override must return actions of shape {expected}, got {actions.shape}")
        largest = float(np.abs(actions).max(initial=0.0))
        if largest > 1.0:
            raise ValueError(f"action_override must return actions in [-1, 1], got a magnitude of {largest}")
        return actions

    def _excluded_save_params(self) -> list[str]:
        """Keep the (callable) override out of saved models."""
        parent = getattr(super(), "_excluded_save_params", None)
        return [*(parent() if parent is not None else []), "action_override"]


class MotorBabblingCallback(BaseCallback):
    """Take over the actions with random babbling for the first ``babbling_steps`` environment steps.

    ``mode="sign"`` draws each component as -1 or +1 (the paper); ``"clamped_uniform"`` draws uniform(-4, 4) and
    clamps to [-1, 1] (the authors' code, about 75% of components at +-1). The draws come from a generator seeded
    with the model's ``seed`` and its step count, so two runs with the same seed babble identically.
    Logs ``rollout/babbling`` (1 while babbling, 0 after).

    :param babbling_steps: number of environment steps (``num_timesteps``) to babble for.
    :param mode: ``"sign"`` or ``"clamped_uniform"``.
    :param verbose: 1 to print when babbling ends.
    """

    def __init__(self, babbling_steps: int, mode: str = "sign", verbose: int = 0):
        super().__init__(verbose)
        if babbling_steps < 0:
            raise ValueError(f"babbling_steps must be >= 0, got {babbling_steps}")
        if mode not in BABBLING_MODES:
            raise ValueError(f"babbling mode must be one of {BABBLING_MODES}, got {mode!r}")
        self.babbling_steps = babbling_steps
        self.mode = mode
        self._action_shape: tuple[int, ...] = ()
        self._rng = np.random.default_rng()

    def _init_callback(self) -> None:
        if not hasattr(self.model, "action_override"):
            raise TypeError(
                f"MotorBabblingCallback needs an algorithm with the babbling hook (ActionOverrideMixin), "
                f"got {type(self.model).__name__}"
            )
        action_space = self.model.action_space
        if not isinstance(action_space, spaces.Box):
            raise TypeError(f"Motor babbling needs a Box action space, got {action_space}")
        self._action_shape = action_space.shape
        seed = getattr(self.model, "seed", None)
        entropy = None if seed is None else [seed % 2**32, self.model.num_timesteps]
        self._rng = np.random.default_rng(entropy)

    @property
    def babbling(self) -> bool:
        """Whether this callback's babbling currently drives the model's actions."""
        return self.model.action_override == self.babble

    def babble(self, n_envs: int) -> np.ndarray:
        """Draw babbling actions (n_envs, *action_shape) in [-1, 1]."""
        shape = (n_envs, *self._action_shape)
        if self.mode == "sign":
            return np.where(self._rng.random(shape) < 0.5, -1.0, 1.0).astype(np.float32)
        return np.clip(self._rng.uniform(-4.0, 4.0, shape), -1.0, 1.0).astype(np.float32)

    def _on_training_start(self) -> None:
        if self.model.num_timesteps < self.babbling_steps:
            self.model.action_override = self.babble

    def _on_step(self) -> bool:
        # The flag says whether the step just taken was a babbling step.
        self.logger.record("rollout/babbling", float(self.babbling))
        if self.babbling and self.model.num_timesteps >= self.babbling_steps:
            self.model.action_override = None
            if self.verbose >= 1:
                print(f"Motor babbling ended after {self.model.num_timesteps} steps")
        return True

    def _on_training_end(self) -> None:
        if self.babbling:
            self.model.action_override = None
