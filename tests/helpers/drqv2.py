"""Tiny pixel envs without MuJoCo for the DrQ-v2 tests, and small model settings that keep them fast."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit

from sb3_ef.envs.toy import ToyAgentEnv

SIZE = 32
FRAME_STACK = 3
EPISODE_STEPS = 20

# Networks small enough for a few CPU updates per second at batch 8-16.
TINY_POLICY: dict[str, Any] = {
    "net_arch": [32, 32],
    "trunk_dim": 16,
    "features_dim": 64,
    "agent_dim": 8,
    "ef_kwargs": {"rollout_hidden_dims": (16,), "decoder_channels": 8},
}
TINY_ALGO: dict[str, Any] = {
    "buffer_size": 500,
    "batch_size": 8,
    "learning_starts": 16,
    "train_freq": 1,
    "ef_horizon": 3,
    "babbling_steps": 0,
}


class CueEnv(gym.Env):
    """Each step shows a cue: the left half of the image lit (+1) or the right half (-1); a moving dot is the agent.

    The reward is ``cue * action[0]``: a random policy earns 0 on average, the best one ``+1`` per step, and only a
    policy that reads the image can earn it. The dot moves with ``action[1]``, so Ego-Foresight has something to
    predict. Frames are stacked along channels, oldest first, as ``sb3_ef.envs`` does.
    """

    metadata: dict[str, Any] = {"render_modes": []}

    def __init__(self, size: int = SIZE, action_dim: int = 2):
        self.size = size
        self.observation_space = spaces.Box(0, 255, (3 * FRAME_STACK, size, size), np.uint8)
        self.action_space = spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
        self._cue = 1.0
        self._dot = size // 2
        self._frames: list[np.ndarray] = []

    def _frame(self) -> np.ndarray:
        frame = np.zeros((3, self.size, self.size), dtype=np.uint8)
        half = self.size // 2
        if self._cue > 0:
            frame[0, :, :half] = 200
        else:
            frame[1, :, half:] = 200
        frame[2, self._dot - 1 : self._dot + 2, self._dot - 1 : self._dot + 2] = 255
        return frame

    def _observation(self) -> np.ndarray:
        return np.concatenate(self._frames[-FRAME_STACK:], axis=0)

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self._cue = float(self.np_random.choice([-1.0, 1.0]))
        self._dot = self.size // 2
        self._frames = [self._frame()] * FRAME_STACK
        return self._observation(), {}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        reward = float(self._cue * np.clip(action[0], -1.0, 1.0))
        self._dot = int(np.clip(self._dot + round(2 * float(action[-1])), 1, self.size - 2))
        self._cue = float(self.np_random.choice([-1.0, 1.0]))
        self._frames.append(self._frame())
        return self._observation(), reward, False, False, {}


def make_cue_env(size: int = SIZE, episode_steps: int = EPISODE_STEPS) -> gym.Env:
    """The cue env with a time limit (the algorithm reads the episode length from it)."""
    return TimeLimit(CueEnv(size), max_episode_steps=episode_steps)


class TerminatingToyEnv(gym.Wrapper):
    """sb3-ef's ``ToyAgentEnv`` whose every second episode ends early, after ``terminate_after`` steps, by a
    termination (``terminated=True``); the others end at its time limit (``truncated=True``)."""

    def __init__(self, env: ToyAgentEnv, terminate_after: int):
        if not 1 <= terminate_after < env.max_episode_steps:
            raise ValueError(
                f"terminate_after must lie in [1, max_episode_steps={env.max_episode_steps}), got {terminate_after}"
            )
        super().__init__(env)
        self.terminate_after = terminate_after
        self._episodes = self._steps = 0

    def reset(self, **kwargs: Any) -> tuple[np.ndarray, dict]:
        self._episodes += 1
        self._steps = 0
        return self.env.reset(**kwargs)

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._steps += 1
        if self._episodes % 2 == 0 and self._steps == self.terminate_after:
            terminated, truncated = True, False
        return observation, float(reward), terminated, truncated, info
