"""A tiny pixel world for testing Ego-Foresight without a simulator: a controlled square and a distractor."""

from __future__ import annotations

from collections import deque
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

AGENT_COLOUR = (255, 0, 0)
DISTRACTOR_COLOUR = (0, 255, 0)
WALL_COLOUR = (0, 0, 160)
#: ``sb3_ef.envs.pixel_env``'s info key of the agent masks (not imported: no MuJoCo here).
AGENT_MASKS_INFO_KEY = "agent_masks"


class ToyAgentEnv(gym.Env):
    """A MuJoCo-free test world: a red agent square, a green random-walk distractor, a blue wall; reward: centring.

    :param size: frame height and width in pixels.
    :param frame_stack: number of stacked frames.
    :param max_episode_steps: episode length, reported as ``truncated``.
    :param distractor: whether to draw the distractor.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(
        self,
        size: int = 32,
        frame_stack: int = 3,
        max_episode_steps: int = 50,
        distractor: bool = True,
        render_mode: str | None = None,
        agent_masks: bool = False,
    ):
        if size < 8:
            raise ValueError(f"size must be >= 8 pixels, got {size}")
        if frame_stack < 1 or max_episode_steps < 1:
            raise ValueError(f"frame_stack and max_episode_steps must be >= 1, got {frame_stack}, {max_episode_steps}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.size = size
        self.frame_stack = frame_stack
        self.max_episode_steps = max_episode_steps
        self.distractor = distractor
        self.render_mode = render_mode
        self.agent_masks = agent_masks
        self.square = max(2, size * 3 // 16)
        self.speed = max(1.0, size / 16)
        self.observation_space = spaces.Box(0, 255, (3 * frame_stack, size, size), np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._frames: deque[np.ndarray] = deque(maxlen=frame_stack)
        self._masks: deque[np.ndarray] = deque(maxlen=frame_stack + 1)
        self._agent = np.zeros(2)
        self._distractor = np.zeros(2)
        self._wall = np.zeros(2, dtype=int)
        self._steps = 0

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        high = self.size - self.square
        self._agent = self.np_random.uniform(0, high, 2)
        self._distractor = self.np_random.uniform(0, high, 2)
        self._wall = self.np_random.integers(0, self.size - self.size // 4, 2)
        self._steps = 0
        frame = self._render_frame()
        self._frames.extend([frame] * self.frame_stack)
        info: dict[str, Any] = {}
        if self.agent_masks:
            self._masks.clear()
            self._masks.extend([self.agent_mask()] * self.frame_stack)
            info[AGENT_MASKS_INFO_KEY] = np.stack(self._masks)
        return self._observation(), info

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        action = np.asarray(action, dtype=np.float64)
        if action.shape != (2,):
            raise ValueError(f"Expected an action of shape (2,), got {action.shape}")
        high = self.size - self.square
        self._agent = np.clip(self._agent + self.speed * np.clip(action, -1, 1), 0, high)
        if self.distractor:  # without one, steps draw no random numbers (resets alone decide an episode)
            walk = self.speed * self.np_random.choice([-1.0, 1.0], 2)
            self._distractor = np.clip(self._distractor + walk, 0, high)
        self._steps += 1
        self._frames.append(self._render_frame())
        centre = (self.size - self.square) / 2
        reward = -float(np.linalg.norm(self._agent - centre)) / self.size
        info: dict[str, Any] = {}
        if self.agent_masks:
            self._masks.append(self.agent_mask())
            info[AGENT_MASKS_INFO_KEY] = np.stack(self._masks)
        return self._observation(), reward, False, self._steps >= self.max_episode_steps, info

    def render(self) -> np.ndarray:
        """The newest frame, (size, size, 3) uint8."""
        return self._frames[-1].transpose(1, 2, 0).copy()

    @property
    def agent_position(self) -> np.ndarray:
        """(row, col) of the agent square's top-left corner, in pixels."""
        return self._agent.copy()

    @property
    def distractor_position(self) -> np.ndarray:
        """(row, col) of the distractor square's top-left corner, in pixels."""
        return self._distractor.copy()

    def agent_mask(self) -> np.ndarray:
        """(size, size) bool: the pixels showing the agent in the newest frame."""
        return self._square_mask(self._agent)

    def distractor_mask(self) -> np.ndarray:
        """(size, size) bool: the visible pixels of the distractor in the newest frame (empty without one)."""
        if not self.distractor:
            return np.zeros((self.size, self.size), dtype=bool)
        return self._square_mask(self._distractor) & ~self.agent_mask()

    def _square_mask(self, corner: np.ndarray) -> np.ndarray:
        row, col = np.rint(corner).astype(int)
        mask = np.zeros((self.size, self.size), dtype=bool)
        mask[row : row + self.square, col : col + self.square] = True
        return mask

    def _render_frame(self) -> np.ndarray:
        frame = np.zeros((self.size, self.size, 3), dtype=np.uint8)
        row, col = self._wall
        frame[row : row + self.size // 4, col : col + self.size // 4] = WALL_COLOUR
        if self.distractor:
            frame[self._square_mask(self._distractor)] = DISTRACTOR_COLOUR
        frame[self.agent_mask()] = AGENT_COLOUR
        return frame.transpose(2, 0, 1)

    def _observation(self) -> np.ndarray:
        return np.concatenate(self._frames, axis=0)
