"""What the algorithms check about their env and replay buffer."""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.preprocessing import is_image_space, is_image_space_channels_first
from stable_baselines3.common.vec_env import VecEnv, VecTransposeImage

from sb3_ef.common.buffers import SequenceReplayBuffer

FRAME_CHANNELS = 3


def policy_observation_space(observation_space: spaces.Space) -> spaces.Space:
    """The observation space an SB3 algorithm gives its policy (channels-last images made channels-first)."""
    if (
        isinstance(observation_space, spaces.Box)
        and is_image_space(observation_space)
        and not is_image_space_channels_first(observation_space)
    ):
        return VecTransposeImage.transpose_space(observation_space)
    return observation_space


def check_stacked_frames(observation_space: spaces.Space, algorithm: str) -> tuple[int, int, int]:
    """Check for stacked uint8 RGB frames, channels-first, and return their ``(channels, height, width)``."""
    if (
        not isinstance(observation_space, spaces.Box)
        or observation_space.dtype != np.uint8
        or len(observation_space.shape) != 3
        or observation_space.shape[0] % FRAME_CHANNELS != 0
    ):
        raise ValueError(
            f"{algorithm} expects stacked RGB frames: a uint8 Box of shape (3 * frame_stack, height, width), "
            f"got {observation_space} (an env's channels-last frames, (height, width, 3 * frame_stack) with bounds "
            "0 and 255, are accepted too: SB3 transposes them)"
        )
    channels, height, width = observation_space.shape
    return channels, height, width


def check_box_actions(action_space: spaces.Space, algorithm: str) -> None:
    if not isinstance(action_space, spaces.Box):
        raise ValueError(f"{algorithm} needs a continuous (Box) action space, got {action_space}")


def sequence_buffer(
    replay_buffer_class: type[ReplayBuffer] | None,
    replay_buffer_kwargs: dict[str, Any],
    why: str,
    horizon: int,
    **defaults: Any,
) -> tuple[type[ReplayBuffer], dict[str, Any]]:
    """An off-policy host's buffer class and arguments: a :class:`SequenceReplayBuffer` (checked, ``why`` says what
    it samples) with the window ``horizon`` and ``defaults`` (such as ``n_steps``, ``gamma``) under the user's."""
    if replay_buffer_class is not None and not issubclass(replay_buffer_class, SequenceReplayBuffer):
        raise ValueError(
            f"{why}: replay_buffer_class must be a SequenceReplayBuffer (sub)class, got {replay_buffer_class.__name__}"
        )
    return replay_buffer_class or SequenceReplayBuffer, {**defaults, **replay_buffer_kwargs, "horizon": horizon}


@contextmanager
def n_steps_given_to_buffer() -> Iterator[None]:
    """Silence SB3's warning that ``n_steps`` is ignored with a custom buffer: the sequence buffer takes them."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom")
        yield


def episode_steps(env: VecEnv) -> int | None:
    """The episode length in agent steps when the env tells it (spec, TimeLimit, sb3-ef's pixel envs), else None."""
    spec = env.get_attr("spec", indices=[0])[0]
    if spec is not None and spec.max_episode_steps is not None:
        return int(spec.max_episode_steps)
    if env.has_attr("_max_episode_steps"):  # a TimeLimit wrapper (asked by name: rl-zoo3 swaps the class)
        return int(env.get_attr("_max_episode_steps", indices=[0])[0])
    if env.has_attr("episode_length") and env.has_attr("action_repeat"):
        episode_length, action_repeat = (
            env.get_attr(name, indices=[0])[0] for name in ("episode_length", "action_repeat")
        )
        return math.ceil(episode_length / action_repeat)
    if env.has_attr("max_episode_steps"):
        return int(env.get_attr("max_episode_steps", indices=[0])[0])
    return None
