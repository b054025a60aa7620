"""Colour distraction: every material's RGB drawn per episode within the suite's range, drifting per step."""

from __future__ import annotations

import mujoco
import numpy as np

from sb3_ef.envs.distracting.settings import ColorSettings


class ColorDistraction:
    """Each material's RGB within ``max_delta`` of its own at reset, moving by ``step_std`` per step when dynamic."""

    def __init__(self, model: mujoco.MjModel, settings: ColorSettings) -> None:
        original = model.mat_rgba[:, :3].copy()
        self.settings = settings
        self._low = np.clip(original - settings.max_delta, 0.0, 1.0)
        self._high = np.clip(original + settings.max_delta, 0.0, 1.0)
        self._rgb = original

    def reset(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """New colours for the episode."""
        self._rgb = self._low + rng.uniform(size=self._low.shape) * (self._high - self._low)
        model.mat_rgba[:, :3] = self._rgb

    def step(self, model: mujoco.MjModel, data: mujoco.MjData, rng: np.random.Generator) -> None:
        """The colours' drift over one simulator step (none with static settings)."""
        if self.settings.step_std > 0:
            drift = rng.standard_normal(self._rgb.shape) * self.settings.step_std
            self._rgb = np.clip(self._rgb + drift, self._low, self._high)
            model.mat_rgba[:, :3] = self._rgb
