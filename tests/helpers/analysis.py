"""Hand-made stand-ins for the analysis tests: they follow the contracts of docs/architecture.md with known answers."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch as th
from torch import nn

SIZE = 16
REGION = 8  # FakeForesight's h_a paints only the top-left REGION x REGION pixels


class FakeForesight(nn.Module):
    """EgoForesight-like module whose decoder lets h_a drive only the top-left region and h_s everything else."""

    def __init__(self, feature_dim: int = 12, action_dim: int = 2, agent_dim: int = 4, size: int = SIZE):
        super().__init__()
        self.agent_dim, self.action_dim, self.size, self.horizon = agent_dim, action_dim, size, 3
        self.target = "pixel"  # it decodes frames, as pixel EF
        self.dynamics = nn.Linear(agent_dim + action_dim, agent_dim)
        self.agent_pixels = nn.Linear(agent_dim, 3 * REGION * REGION)
        self.scene_pixels = nn.Linear(feature_dim - agent_dim, 3 * size * size)
        self.norm = nn.BatchNorm1d(3 * size * size)  # eval mode must be used: a batch of one would fail in train

    def split(self, h: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return h[:, self.agent_dim :], h[:, : self.agent_dim]

    def rollout(self, h_agent: th.Tensor, actions: th.Tensor) -> th.Tensor:
        states = []
        for step in range(actions.shape[1]):
            h_agent = th.tanh(self.dynamics(th.cat([h_agent, actions[:, step]], dim=1)))
            states.append(h_agent)
        return th.stack(states, dim=1)

    def decode(self, h_scene: th.Tensor, h_agent: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        scene = self.norm(self.scene_pixels(h_scene)).view(-1, 3, self.size, self.size)
        agent = self.agent_pixels(h_agent).view(-1, 3, REGION, REGION)
        top = th.cat([agent, scene[:, :, :REGION, REGION:]], dim=3)
        return th.sigmoid(th.cat([top, scene[:, :, REGION:]], dim=2))

    def predict(self, h: th.Tensor, actions: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        h_scene, h_agent = self.split(h)
        states = self.rollout(h_agent, actions)
        return th.stack([self.decode(h_scene, states[:, t]) for t in range(actions.shape[1])], dim=1)


class FakeModel:
    """Model object with the EF contract (ef, encode, frame_shape) plus what a BaseCallback needs."""

    def __init__(self, logger=None):
        self.ef = FakeForesight()
        self.encoder = nn.Linear(9 * SIZE * SIZE, 12)
        self.frame_shape = (3, SIZE, SIZE)
        self.action_space = gym.spaces.Box(-1, 1, (2,), np.float32)
        self.logger = logger
        self.num_timesteps = 0

    def encode(self, observations: th.Tensor) -> th.Tensor:
        return self.encoder(observations.float().flatten(1) / 255 - 0.5)

    def predict(self, observation, state=None, episode_start=None, deterministic=False):
        return np.array([0.5, -0.5], dtype=np.float32), state

    def get_env(self):
        return None


class DotEnv(gym.Env):
    """A red 3x3 dot moved by 2-D actions on a grey background; stacked frames, channels-first, with agent_mask."""

    def __init__(self, size: int = SIZE, frame_stack: int = 3):
        self.size, self.frame_stack = size, frame_stack
        self.observation_space = gym.spaces.Box(0, 255, (3 * frame_stack, size, size), np.uint8)
        self.action_space = gym.spaces.Box(-1, 1, (2,), np.float32)
        self.position = np.zeros(2)
        self.frames: list[np.ndarray] = []

    def agent_mask(self) -> np.ndarray:
        mask = np.zeros((self.size, self.size), dtype=bool)
        row, column = self.position.astype(int)
        mask[row : row + 3, column : column + 3] = True
        return mask

    def _frame(self) -> np.ndarray:
        frame = np.full((3, self.size, self.size), 100, dtype=np.uint8)
        frame[:, self.agent_mask()] = np.array([255, 0, 0], dtype=np.uint8)[:, None]
        return frame

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.position = self.np_random.uniform(0, self.size - 3, size=2)
        self.frames = [self._frame()] * self.frame_stack
        return np.concatenate(self.frames), {}

    def step(self, action):
        self.position = np.clip(self.position + 2 * np.asarray(action), 0, self.size - 3)
        self.frames = [*self.frames[1:], self._frame()]
        return np.concatenate(self.frames), 0.0, False, False, {}
