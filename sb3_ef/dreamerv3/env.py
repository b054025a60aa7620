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


class StepLocals(gym.Wrapper):
    """Writes each step into ``locals_`` as SB3's callbacks read it from a one-env ``DummyVecEnv``: batched
    ``actions``, ``new_obs``, ``rewards``, ``dones`` and ``infos``; at an episode's end ``new_obs`` is the next
    episode's first observation (sheeprl's vector env resets in the same step) and ``infos[0]["terminal_observation"]``
    the last one."""

    def __init__(self, env: gym.Env, locals_: dict[str, Any]):
        super().__init__(env)
        self.locals = locals_

    def step(self, action: Any) -> Any:
        result = observation, reward, terminated, truncated, info = self.env.step(action)
        done = bool(terminated or truncated)
        info = {**info, "TimeLimit.truncated": bool(truncated and not terminated)}
        if done:
            info["terminal_observation"] = observation
        self.locals.update(
            actions=np.asarray(action)[np.newaxis], new_obs=observation[np.newaxis],
            rewards=np.array([reward], dtype=np.float32), dones=np.array([done]), infos=[info],
        )  # fmt: skip
        return result

    def reset(self, **kwargs: Any) -> Any:
        observation, info = self.env.reset(**kwargs)
        if "new_obs" in self.locals:  # the reset after an episode's end
            self.locals["new_obs"] = observation[np.newaxis]
        return observation, info


class _KeptOpen(gym.Wrapper):
    """An env sheeprl's ``close`` leaves open: it belongs to the caller, as with SB3."""

    def close(self) -> None:
        pass


def live_env(token: str) -> gym.Env:
    """Hydra target of sheeprl's ``env.wrapper``: the registered env's newest frames, left open by sheeprl."""
    env = live.lookup(token)
    return _KeptOpen(NewestFrame(env))
