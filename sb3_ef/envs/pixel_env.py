"""Base class of the pixel environments; a suite subclass owns the simulator and implements three hooks."""

from __future__ import annotations

from collections import deque
from functools import partial
from typing import Any

import gymnasium as gym
import mujoco
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding

from sb3_ef.envs.agent_geoms import agent_geoms
from sb3_ef.envs.renderer import FrameRenderer

AGENT_MASKS_INFO_KEY = "agent_masks"


class PixelEnv(gym.Env[np.ndarray, np.ndarray]):
    """Pixel observations of a MuJoCo simulation (docs/envs.md); subclasses call :meth:`_setup` once it exists."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"]}
    #: Infos carry each frame's agent mask: reset's ``(frame_stack, size, size)``, step's ``(frame_stack + 1, ...)``
    #: (``[:-1]``: the observation acted on, ``[1:]``: the new one); see docs/envs.md "Agent masks".
    agent_masks: bool = False

    def _setup(
        self,
        model: mujoco.MjModel,
        action_dim: int,
        sim_timestep: float,
        camera: int | str,
        flip: bool,
        seed: int | None = None,
        size: int = 84,
        frame_stack: int = 3,
        action_repeat: int = 2,
        episode_length: int = 1000,
        fast_render: bool = False,
        render_mode: str | None = None,
    ) -> None:
        """Set up from :func:`~sb3_ef.envs.factory.make_env`'s options; ``seed`` seeds ``np_random``."""
        for argument, value in (("frame_stack", frame_stack), ("action_repeat", action_repeat)):
            if not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{argument} must be an int >= 1, got {value!r}")
        if not isinstance(episode_length, (int, np.integer)) or episode_length < 1:
            raise ValueError(f"episode_length must be an int >= 1 (simulator steps), got {episode_length!r}")
        if render_mode not in (None, *self.metadata["render_modes"]):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        if seed is not None:
            self.np_random, _ = seeding.np_random(seed)
        self.size, self.fast_render = size, fast_render
        self.frame_stack = frame_stack
        self.action_repeat = action_repeat
        self.episode_length = episode_length
        self.render_mode = render_mode
        self.metadata = {**self.metadata, "render_fps": round(1.0 / (sim_timestep * action_repeat))}
        self.observation_space = spaces.Box(0, 255, (3 * frame_stack, size, size), np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
        self._open_renderer = partial(
            FrameRenderer, model, size, camera, fast=fast_render, flip=flip, agent_geoms=agent_geoms(model)
        )
        self._renderer: FrameRenderer | None = self._open_renderer()
        self._camera = self._renderer.camera
        self._frames: deque[np.ndarray] = deque(maxlen=frame_stack)
        self._masks: deque[np.ndarray] | None = None  # the last frame_stack + 1 frames' masks
        self._sim_steps = 0
        self._episode_over = True

    def _physics(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The simulator's current model and data."""
        raise NotImplementedError

    def _reset_sim(self, seed: int | None, options: dict[str, Any] | None) -> dict[str, Any]:
        """Start a new episode in the simulator (re-seeded when ``seed`` is given); return the info dict."""
        raise NotImplementedError

    def _step_sim(self, action: np.ndarray) -> tuple[float, bool, dict[str, Any]]:
        """One simulator step with an action in [-1, 1]: ``(reward, terminated, info)``."""
        raise NotImplementedError

    def _simulator_seed(self) -> int:
        """A seed for the simulator's generator, drawn from ``np_random`` (which checkpoints record)."""
        return int(self.np_random.integers(2**31))

    @property
    def camera(self) -> int:
        """Index of the camera that renders the observations."""
        return self._camera

    def _frame_renderer(self) -> FrameRenderer:
        """The renderer, opened again when the env is used after ``close()`` (as SB3's ``check_env`` does)."""
        if self._renderer is None:
            self._renderer = self._open_renderer()
        return self._renderer

    def _observation(self) -> np.ndarray:
        return np.concatenate(self._frames, axis=0)

    def _render_frame(self) -> np.ndarray:
        return self._frame_renderer().rgb(self._physics()[1]).transpose(2, 0, 1)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        info = self._reset_sim(seed, options)
        self._sim_steps = 0
        self._episode_over = False
        self._frames.extend([self._render_frame()] * self.frame_stack)
        self._masks = None
        if self.agent_masks:
            self._masks = deque([self.agent_mask()] * self.frame_stack, maxlen=self.frame_stack + 1)
            info[AGENT_MASKS_INFO_KEY] = np.stack(self._masks)
        return self._observation(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._episode_over:
            raise RuntimeError("Call reset() before step(): the episode has not started or has ended")
        action = np.asarray(action, dtype=np.float32)
        if action.shape != self.action_space.shape:
            raise ValueError(f"Expected an action of shape {self.action_space.shape}, got shape {action.shape}")
        reward, terminated, success = 0.0, False, None
        for _ in range(self.action_repeat):
            step_reward, terminated, info = self._step_sim(action)
            reward += step_reward
            self._sim_steps += 1
            if "is_success" in info:
                success = bool(success) or bool(info["is_success"])
            if terminated or self._sim_steps >= self.episode_length:
                break
        truncated = not terminated and self._sim_steps >= self.episode_length
        self._episode_over = terminated or truncated
        if success is not None:
            info["is_success"] = success
        self._frames.append(self._render_frame())
        if self.agent_masks:
            info[AGENT_MASKS_INFO_KEY] = self._step_masks()
        return self._observation(), reward, terminated, truncated, info

    def _step_masks(self) -> np.ndarray:
        """The masks of the previous observation's frames and of the frame just rendered, oldest first."""
        if self._masks is None:
            raise RuntimeError("agent_masks was turned on during an episode: call reset() to start one with masks")
        self._masks.append(self.agent_mask())
        return np.stack(self._masks)

    def agent_mask(self) -> np.ndarray:
        """``(size, size)`` bool mask of the agent's pixels (:func:`~sb3_ef.envs.agent_geoms.agent_geoms`) now."""
        return self._frame_renderer().agent_mask(self._physics()[1])

    def segmentation(self) -> np.ndarray:
        """``(size, size)`` ids of the geom seen at each pixel now, -1 where none."""
        return self._frame_renderer().geom_ids(self._physics()[1])

    @property
    def mujoco_state(self) -> tuple[mujoco.MjModel, mujoco.MjData]:
        """The simulator's model and data: to name geoms, read or move objects between steps."""
        return self._physics()

    def render(self) -> np.ndarray | None:
        """The newest frame as ``(size, size, 3)`` uint8 (no extra rendering) when ``render_mode='rgb_array'``."""
        if self.render_mode is None or not self._frames:
            return None
        return self._frames[-1].transpose(1, 2, 0)

    def close(self) -> None:
        """Free the renderer's OpenGL context; the simulator is kept, so a later ``reset()`` opens a new one."""
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        super().close()
