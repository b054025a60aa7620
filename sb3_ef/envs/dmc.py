"""DeepMind Control Suite tasks from pixels: shimmy's dm-control wrapper for the dynamics, sb3-ef's renderer."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from dm_control import suite
from dm_control.suite import quadruped
from shimmy import DmControlCompatibilityV0

from sb3_ef.envs.pixel_env import PixelEnv
from sb3_ef.envs.tasks import DMC_TASKS


def _quadruped_sensor_names(physics: quadruped.Physics, *sensor_types: int) -> list[str]:
    """dm-control 1.0.28's quadruped sensor lookup, with ``np.isin`` for ``np.in1d`` (removed in numpy 2.4)."""
    if sensor_types not in physics._sensor_types_to_names:
        sensor_ids = np.flatnonzero(np.isin(physics.model.sensor_type, sensor_types))
        physics._sensor_types_to_names[sensor_types] = [physics.model.id2name(i, "sensor") for i in sensor_ids]
    return physics._sensor_types_to_names[sensor_types]


if not hasattr(np, "in1d"):
    quadruped.Physics._get_sensor_names = _quadruped_sensor_names

#: Default camera per domain (camera 0 otherwise), as in DrQ-v2 / TD-MPC2.
DEFAULT_CAMERAS: dict[str, int] = {"quadruped": 2}


class DMCPixelEnv(PixelEnv):
    """A dm-control suite task with pixel observations; the arguments are :func:`~sb3_ef.envs.factory.make_env`'s."""

    def __init__(self, task: str, camera: int | str | None = None, seed: int | None = None, **options: Any) -> None:
        domain, suite_task = DMC_TASKS[task]
        self.task = task
        dm_env = suite.load(domain, suite_task, task_kwargs={"random": seed, "time_limit": float("inf")})
        self._env = DmControlCompatibilityV0(dm_env)
        spec = dm_env.action_spec()
        self._action_low, self._action_high = spec.minimum.astype(np.float64), spec.maximum.astype(np.float64)
        try:
            camera = DEFAULT_CAMERAS.get(domain, 0) if camera is None else camera
            self._setup(self._physics()[0], spec.shape[0], dm_env.control_timestep(), camera, False, seed, **options)
        except Exception:
            self._env.close()
            raise

    def _physics(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        physics = self._env.physics
        return physics.model.ptr, physics.data.ptr

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, Any]:
        # dm_control draws the initial state from the task's generator, reseeded here from the env's every episode
        return self._env.reset(seed=self._simulator_seed(), options=options)[1]

    def _step_sim(self, action: np.ndarray) -> tuple[float, bool, dict[str, Any]]:
        scaled = self._action_low + (action.astype(np.float64) + 1.0) * 0.5 * (self._action_high - self._action_low)
        _, reward, terminated, _, info = self._env.step(scaled)
        return float(reward), terminated, info
