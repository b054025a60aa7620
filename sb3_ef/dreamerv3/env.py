"""What Dreamer-v3 sees of an sb3-ef env: the newest RGB frame of its stacked observation."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from sb3_ef.common.env_checks import FRAME_CHANNELS, check_box_actions, check_stacked_frames
from sb3_ef.dreamerv3 import live


def task_id(env: gym.Env) -> str:
    """sheeprl's ``env.id`` (a resumed run must share it): the gymnasium id with ``-`` for ``/``, or the class name."""
    name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    return name.replace("/", "-")


def check_frame_size(height: int, width: int) -> None:
    """Dreamer-v3's encoder halves square frames down to 4x4: the size must be a power of 2 (16, 32, 64, ...)."""
    if height != width or height < 8 or height & (height - 1):
        raise ValueError(
            f"DreamerV3 needs square frames whose size is a power of 2 (e.g. make_env(..., size=64)), "
            f"got {height}x{width}"
        )


class NewestFrame(gym.ObservationWrapper):
    """The newest RGB frame of an env of stacked frames.

    :param env: an env of stacked uint8 RGB frames, channels-first, with Box actions.
    """

    def __init__(self, env: gym.Env):
        _, height, width = check_stacked_frames(env.observation_space, "DreamerV3")
        check_box_actions(env.action_space, "DreamerV3")
        check_frame_size(height, width)
        super().__init__(env)
        self.observation_space = spaces.Box(0, 255, (FRAME_CHANNELS, height, width), np.uint8)

    def observation(self, observation: np.ndarray) -> np.ndarray:
        return observation[-FRAME_CHANNELS:]


class StopTraining(BaseException):
    """An SB3 callback returned ``False`` (a ``BaseException``: sheeprl's ``RestartOnException`` passes it)."""


class StepCallbacks(gym.Wrapper):
    """Counts env steps on ``model.num_timesteps`` and calls ``callback.on_step()`` after each, as SB3 does."""

    def __init__(self, env: gym.Env, model: Any, callback: Any, locals_: dict[str, Any]):
        super().__init__(env)
        self.model, self.callback, self.locals = model, callback, locals_

    def step(self, action: Any) -> Any:
        result = self.env.step(action)
        observation, reward, terminated, truncated, info = result
        self.model.num_timesteps += 1
        self.locals.update(
            actions=action, new_obs=observation, rewards=reward, dones=terminated or truncated, infos=[info]
        )
        if not self.callback.on_step():
            raise StopTraining(f"a callback stopped the training at step {self.model.num_timesteps}")
        return result


class _KeptOpen(gym.Wrapper):
    """An env sheeprl's ``close`` leaves open: it belongs to the caller, as with SB3."""

    def close(self) -> None:
        pass


def live_env(token: str) -> gym.Env:
    """Hydra target of sheeprl's ``env.wrapper``: the registered env's newest frames, left open by sheeprl."""
    env = live.lookup(token)
    return _KeptOpen(NewestFrame(env))
