"""What every Ego-Foresight host algorithm shares: input checks, the episode length, motor babbling at ``learn``
and the EF accessors that ``sb3_ef.analysis`` reads. DrQv2EF and TDMPC2EF keep only their own update."""

from __future__ import annotations

import math
from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback, CallbackList, ConvertCallback
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.type_aliases import MaybeCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.common.callbacks import ActionOverrideMixin, MotorBabblingCallback
from sb3_ef.ef import EgoForesight

FRAME_CHANNELS = 3

SelfEFHost = TypeVar("SelfEFHost", bound="EFHostMixin")


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
            f"got {observation_space}"
        )
    channels, height, width = observation_space.shape
    return channels, height, width


def check_box_actions(action_space: spaces.Space, algorithm: str) -> None:
    if not isinstance(action_space, spaces.Box):
        raise ValueError(f"{algorithm} needs a continuous (Box) action space, got {action_space}")


def check_sequence_buffer(replay_buffer_class: type[ReplayBuffer] | None, why: str) -> None:
    """``why`` says what the algorithm samples that only a :class:`SequenceReplayBuffer` provides."""
    if replay_buffer_class is not None and not issubclass(replay_buffer_class, SequenceReplayBuffer):
        raise ValueError(
            f"{why}: replay_buffer_class must be a SequenceReplayBuffer (sub)class, got {replay_buffer_class.__name__}"
        )


def check_ef_arguments(beta: float, ef_horizon: int, babbling_steps: int, plain_variant: str) -> None:
    """Check EF's algorithm-level arguments; ``plain_variant`` names the class to use without EF."""
    if beta is None or not beta > 0:
        raise ValueError(
            f"beta must be a positive number (use {plain_variant} to train without Ego-Foresight), got {beta!r}"
        )
    if not isinstance(ef_horizon, int) or ef_horizon < 1:
        raise ValueError(f"ef_horizon must be a positive integer, got {ef_horizon!r}")
    if babbling_steps < 0:
        raise ValueError(f"babbling_steps must be >= 0, got {babbling_steps}")


def episode_steps(env: VecEnv) -> int | None:
    """The episode length in agent steps when the env tells it: its spec, a TimeLimit wrapper, the attributes of
    sb3-ef's pixel envs (``episode_length`` simulator steps at ``action_repeat``) or ``max_episode_steps``."""
    spec = env.get_attr("spec", indices=[0])[0]
    if spec is not None and spec.max_episode_steps is not None:
        return int(spec.max_episode_steps)
    if env.env_is_wrapped(TimeLimit, indices=[0])[0]:
        return int(env.get_attr("_max_episode_steps", indices=[0])[0])
    if env.has_attr("episode_length") and env.has_attr("action_repeat"):
        episode_length, action_repeat = (
            env.get_attr(name, indices=[0])[0] for name in ("episode_length", "action_repeat")
        )
        return math.ceil(episode_length / action_repeat)
    if env.has_attr("max_episode_steps"):
        return int(env.get_attr("max_episode_steps", indices=[0])[0])
    return None


def check_horizon_fits_episodes(ef_horizon: int | None, steps: int | None) -> None:
    if ef_horizon is not None and steps is not None and ef_horizon > steps:
        raise ValueError(
            f"ef_horizon must not exceed the episode length: expected ef_horizon <= {steps}, got {ef_horizon}"
        )


def _as_callback_list(callback: MaybeCallback) -> list[BaseCallback]:
    if callback is None:
        return []
    if isinstance(callback, list):
        return callback
    if isinstance(callback, BaseCallback):
        return [callback]
    return [ConvertCallback(callback)]


class EFHostMixin(ActionOverrideMixin):
    """Mixed into an SB3 ``OffPolicyAlgorithm`` that trains Ego-Foresight on its encoder.

    - ``model.ef``, ``model.encode(obs)`` and ``model.frame_shape`` (docs/architecture.md) come from the policy,
      which provides ``ef``, ``encode`` and ``frame_shape``.
    - ``learn`` puts a :class:`MotorBabblingCallback` in front of the user's callbacks when ``babbling_steps > 0``.
    - ``_sample_action``: the babbling override, else uniform warm-up actions before ``learning_starts``, else the
      host's own :meth:`_exploration_action` (SB3's ``action_noise`` is not used).
    """

    # Whether the class trains Ego-Foresight; the plain variants (DrQv2, TDMPC2) turn it off.
    uses_ef: ClassVar[bool] = True
    babbling_steps: int
    babbling_mode: str

    @property
    def ef(self) -> EgoForesight | None:
        """The Ego-Foresight module, or ``None`` when EF is off."""
        return self.policy.ef

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape ``(3, height, width)`` of one RGB frame."""
        return self.policy.frame_shape

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of uint8 stacked observations (no augmentation; gradients flow if the caller wants them)."""
        return self.policy.encode(observations.to(self.device))

    def _exploration_action(self, n_envs: int) -> np.ndarray:
        """The host's exploration action for each env, scaled to [-1, 1] (the buffer action)."""
        raise NotImplementedError

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        buffer_action = self._override_actions(n_envs)
        if buffer_action is None:
            if self.num_timesteps < learning_starts:
                uniform = np.array([self.action_space.sample() for _ in range(n_envs)])
                buffer_action = self.policy.scale_action(uniform)
            else:
                buffer_action = self._exploration_action(n_envs)
        return self.policy.unscale_action(buffer_action), buffer_action

    def learn(
        self: SelfEFHost,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfEFHost:
        """SB3's ``learn``, with motor babbling first when ``babbling_steps > 0``; ``tb_log_name`` defaults to the
        class name."""
        if self.babbling_steps > 0:
            babbling = MotorBabblingCallback(self.babbling_steps, mode=self.babbling_mode)
            callback = CallbackList([babbling, *_as_callback_list(callback)])
        learn: Any = super().learn  # type: ignore[misc]
        return learn(
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
