"""Meta-World (metaworld 3.x, ``-v3`` tasks) from pixels, single-task as in the paper; see docs/envs.md."""

from __future__ import annotations

from typing import Any

import mujoco
import numpy as np
from gymnasium import spaces
from metaworld.env_dict import ALL_V3_ENVIRONMENTS

from sb3_ef.envs.pixel_env import PixelEnv
from sb3_ef.envs.renderer import camera_id

#: Cameras that metaworld 3.x renders upside down (their up axis points down); their frames are flipped.
FLIPPED_CAMERAS: frozenset[str] = frozenset({"corner", "corner2", "corner3", "corner4"})

#: The per-simulator-step discount of the EF authors' Meta-World protocol (``repeat_discount``).
AUTHORS_DISCOUNT = 0.99


def authors_gamma(action_repeat: int = 2, discount: float = AUTHORS_DISCOUNT) -> float:
    """The EF authors' per-agent-step ``gamma`` with ``repeat_discount=discount`` (their buffer discounts once more)."""
    return discount ** (action_repeat + 1)


class MetaWorldPixelEnv(PixelEnv):
    """A Meta-World task with pixel observations; the other arguments are :func:`~sb3_ef.envs.factory.make_env`'s.

    :param resample_task: draw a new task variant at every reset instead of keeping the seed's one.
    :param repeat_discount: the reward of an agent step is ``r1 + repeat_discount * r2 + ...`` (1: summed).
    """

    def __init__(
        self,
        task: str,
        camera: int | str | None = None,
        seed: int | None = None,
        episode_length: int = 500,
        resample_task: bool = False,
        repeat_discount: float = 1.0,
        **options: Any,
    ) -> None:
        if not isinstance(repeat_discount, (int, float)) or not 0 < repeat_discount <= 1:
            raise ValueError(f"repeat_discount must be a number in (0, 1], got {repeat_discount!r}")
        self.task = task
        self.resample_task = resample_task
        self.repeat_discount = float(repeat_discount)
        self._repeat_weight = 1.0
        self._env = ALL_V3_ENVIRONMENTS[f"{task}-v3"]()
        # Task variants come from the env's own seeded generator instead of a Meta-World benchmark's task list.
        self._env._set_task_called = True
        self._env.seeded_rand_vec = True
        self._env.max_path_length = episode_length
        if seed is not None:
            self._env.seed(seed)
        try:
            action_space = self._env.action_space
            assert isinstance(action_space, spaces.Box)  # Meta-World's is Box(4,)
            model = self._env.model
            camera_index = camera_id(model, "corner" if camera is None else camera)
            flip = model.camera(camera_index).name in FLIPPED_CAMERAS
            options["episode_length"] = episode_length
            self._setup(model, action_space.shape[0], self._env.dt, camera_index, flip, seed, **options)
        except Exception:
            self._env.close()
            raise

    def _physics(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        return self._env.model, self._env.data

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, Any]:
        if seed is not None:
            self._env.seed(seed)
        elif self.resample_task:  # reseed Meta-World's variant generator from the env's
            self._env.seed(self._simulator_seed())
        draw_variant = seed is not None or self.resample_task or self._env._last_rand_vec is None
        self._env._freeze_rand_vec = not draw_variant
        try:
            _, info = self._env.reset()
        finally:
            self._env._freeze_rand_vec = True
        return info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        self._repeat_weight = 1.0  # the first simulator step of an agent step counts fully
        return super().step(action)

    def _step_sim(self, action: np.ndarray) -> tuple[float, bool, dict[str, Any]]:
        _, reward, terminated, _, info = self._env.step(action)
        reward = float(reward) * self._repeat_weight
        self._repeat_weight *= self.repeat_discount
        return reward, terminated, {**info, "is_success": bool(info["success"])}

    def state_observation(self) -> np.ndarray:
        """Meta-World's state vector (hand, gripper, object poses, goal), the input of ``metaworld.policies``."""
        return self._env._get_obs()

    def close(self) -> None:
        super().close()
        self._env.close()
