"""Meta-World (metaworld 3.x, ``-v3`` tasks) from pixels.

Single-task setting as in the paper: one task variant (object and goal positions) drawn from the env's seed and
kept for every episode, or re-drawn at each reset with ``resample_task=True``. Episodes are truncated after 500
simulator steps; ``info["is_success"]`` carries Meta-World's success flag.

``repeat_discount`` reproduces the EF authors' Meta-World protocol (their public code): the discount 0.99 applied
per simulator step inside action repeat, so one agent step's reward is ``r1 + 0.99 r2``; with their agent
discount on top, the matching ``gamma`` is :func:`authors_gamma` (0.99^3 = 0.970299 per agent step).
"""

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
    """The per-agent-step ``gamma`` that, with ``repeat_discount=discount``, gives the EF authors' discounting.

    Their action-repeat wrapper discounts by ``discount`` per simulator step (``discount ** action_repeat`` per agent
    step) and their replay buffer multiplies by ``discount`` again: ``discount ** (action_repeat + 1)``, 0.970299 at
    action repeat 2 (n-step factor 0.970299^3 = 0.9135 for 3 steps).
    """
    return discount ** (action_repeat + 1)


class MetaWorldPixelEnv(PixelEnv):
    """A Meta-World task with pixel observations (see :class:`~sb3_ef.envs.pixel_env.PixelEnv`).

    :param task: task name without version, e.g. ``"door-open"`` (see :data:`~sb3_ef.envs.tasks.METAWORLD_TASKS`).
    :param size: frame height and width.
    :param frame_stack: frames stacked along channels, oldest first.
    :param action_repeat: simulator steps per agent step.
    :param camera: camera index or name (default ``"corner"``; also corner2, corner3, corner4, topview, ...).
    :param fast_render: shadows, reflections and multisampling off (several times faster on CPU).
    :param seed: seed of the task variant and of the env's randomness.
    :param episode_length: simulator steps before truncation (500 as in the paper).
    :param resample_task: draw a new task variant at every reset instead of keeping the seed's one.
    :param repeat_discount: weight of each further simulator step's reward inside one agent step: the reward is
        ``r1 + repeat_discount * r2 + ...``; 1 (default) sums them, 0.99 is the EF authors' protocol.
    :param render_mode: ``None`` or ``"rgb_array"`` (``render()`` returns the newest frame).
    """

    def __init__(
        self,
        task: str,
        size: int = 84,
        frame_stack: int = 3,
        action_repeat: int = 2,
        camera: int | str | None = None,
        fast_render: bool = False,
        seed: int | None = None,
        episode_length: int = 500,
        resample_task: bool = False,
        repeat_discount: float = 1.0,
        render_mode: str | None = None,
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
            self._setup(
                model,
                action_dim=action_space.shape[0],
                sim_timestep=self._env.dt,
                size=size,
                frame_stack=frame_stack,
                action_repeat=action_repeat,
                episode_length=episode_length,
                camera=camera_index,
                fast_render=fast_render,
                flip=model.camera(camera_index).name in FLIPPED_CAMERAS,
                render_mode=render_mode,
                seed=seed,
            )
        except Exception:
            self._env.close()
            raise

    def _physics(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        return self._env.model, self._env.data

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, Any]:
        if seed is not None:
            self._env.seed(seed)
        elif self.resample_task:  # the variant is drawn from Meta-World's generator: reseed it from the env's
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
        """Meta-World's own state vector (hand position, gripper, object poses, goal): the input of the
        scripted policies in ``metaworld.policies``."""
        return self._env._get_obs()

    def close(self) -> None:
        super().close()
        self._env.close()
