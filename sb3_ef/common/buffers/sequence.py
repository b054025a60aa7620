"""``SequenceReplayBuffer``: SB3's replay buffer over per-env frame rings, each frame stored once (docs/buffer.md)."""

from __future__ import annotations

import math
import os
from typing import Any, cast

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, ReplayBuffer
from stable_baselines3.common.utils import get_device
from stable_baselines3.common.vec_env import VecNormalize

from sb3_ef.common.buffers import persistence
from sb3_ef.common.buffers.episodes import EpisodeRings
from sb3_ef.common.buffers.sampling import BatchSampler, SequenceReplayBufferSamples
from sb3_ef.common.buffers.sb3_arrays import StackedFrameView, sb3_rows, step_array_property
from sb3_ef.common.buffers.storage import FrameStorage, storage_request


def _check_observation_space(observation_space: spaces.Space, frame_channels: int) -> int:
    """The frame stack k of a uint8 ``Box(0, 255, (frame_channels * k, h, w))``, or raise."""
    expected = f"a uint8 Box of shape ({frame_channels} * frame_stack, height, width)"
    if not isinstance(observation_space, spaces.Box):
        raise ValueError(f"SequenceReplayBuffer expects {expected}, got {observation_space}")
    if observation_space.dtype != np.uint8 or len(observation_space.shape) != 3:
        raise ValueError(
            f"SequenceReplayBuffer expects {expected}, got dtype {observation_space.dtype} "
            f"and shape {observation_space.shape}"
        )
    channels = observation_space.shape[0]
    if frame_channels < 1 or channels < frame_channels or channels % frame_channels != 0:
        raise ValueError(
            f"SequenceReplayBuffer expects {expected}: channels must be a positive multiple of "
            f"frame_channels={frame_channels}, got {channels} channels"
        )
    return channels // frame_channels


class SequenceReplayBuffer(ReplayBuffer):
    """SB3 ``replay_buffer_class`` for stacked uint8 frames that keeps each frame once (SB3's arrays are derived).

    :param buffer_size: capacity in frames, split between the envs (an episode of T steps uses T + frame_stack).
    :param observation_space: ``Box(0, 255, (frame_channels * k, h, w), uint8)``, frames stacked oldest first.
    :param action_space: a ``Box`` action space.
    :param device: torch device of the sampled tensors (the training device).
    :param n_envs: number of parallel environments.
    :param optimize_memory_usage: must be False (frames are always stored once).
    :param handle_timeout_termination: when True, ``infos[i]["TimeLimit.truncated"]`` bootstraps (a time limit).
    :param n_steps: number of steps summed in the n-step return.
    :param gamma: discount of the n-step return.
    :param horizon: length H of the Ego-Foresight window (future actions, frames, rewards).
    :param frame_channels: channels of one frame (3 for RGB).
    :param memmap_dir: keep the frames in an unnamed temporary file in this folder (``np.memmap``) rather than RAM.
    :param storage_device: ``"cpu"``, a CUDA device, or ``"auto"``: the training device when the buffer fits.
    :param prefetch: gather the next batch in a background thread (``None``: when host storage feeds CUDA).
    :param store_masks: store the agent masks of ``infos[i]["agent_masks"]``, returned in ``sample().masks``.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        n_steps: int = 1,
        gamma: float = 0.99,
        horizon: int = 10,
        frame_channels: int = 3,
        memmap_dir: str | os.PathLike | None = None,
        storage_device: str | th.device = "auto",
        prefetch: bool | None = None,
        store_masks: bool = False,
    ):
        frame_stack = _check_observation_space(observation_space, frame_channels)
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"SequenceReplayBuffer expects a Box action space, got {action_space}")
        if optimize_memory_usage:
            raise ValueError(
                "SequenceReplayBuffer expects optimize_memory_usage=False (it always stores each frame once), got True"
            )
        for name, value in (("n_steps", n_steps), ("horizon", horizon), ("n_envs", n_envs)):
            if value < 1:
                raise ValueError(f"SequenceReplayBuffer expects {name} >= 1, got {value}")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"SequenceReplayBuffer expects 0 <= gamma <= 1, got {gamma}")
        capacity = buffer_size // n_envs
        if capacity <= horizon + frame_stack:
            raise ValueError(
                f"SequenceReplayBuffer expects buffer_size // n_envs > horizon + frame_stack = {horizon + frame_stack} "
                f"frames per env (one window and its context), got {buffer_size} // {n_envs} = {capacity}"
            )
        request = storage_request(storage_device)
        if memmap_dir is not None and isinstance(request, th.device) and request.type != "cpu":
            raise ValueError(
                f"SequenceReplayBuffer keeps memory-mapped frames in host memory: memmap_dir expects "
                f"storage_device 'cpu' or 'auto', got {storage_device!r}"
            )
        # ReplayBuffer.__init__ would allocate full observation arrays.
        BaseBuffer.__init__(self, buffer_size, observation_space, action_space, device, n_envs=n_envs)
        self.buffer_size = capacity
        self.optimize_memory_usage = False
        self.handle_timeout_termination = handle_timeout_termination
        self.n_steps = n_steps
        self.gamma = gamma
        self.horizon = horizon
        self.frame_channels = frame_channels
        self.frame_stack = frame_stack
        _, height, width = cast(spaces.Box, observation_space).shape  # a Box: checked above
        self.frame_shape = (frame_channels, height, width)
        self.memmap_dir = None if memmap_dir is None else os.fspath(memmap_dir)
        self.storage_request = request
        self.store_masks = bool(store_masks)
        # Seeded from torch's initial seed (SB3 sets it): seeded runs draw the same batches, on a stream of their own.
        self._build_parts(prefetch, seed=th.initial_seed())
        # Chosen now, allocated at the first add(): SB3's load rebuilds this buffer for models loaded only to act.
        self.storage_device = self._storage.choose_device(request, self.device)

    def _build_parts(self, prefetch: bool | None, seed: int = 0) -> None:
        height, width = self.frame_shape[1:]
        self._rings = EpisodeRings(self.n_envs, self.buffer_size, self.frame_stack, self.frame_channels, self.obs_shape)
        self._storage = FrameStorage(
            self.n_envs * self.buffer_size,
            self.frame_shape,
            self.action_dim,
            math.ceil(height * width / 8) if self.store_masks else None,
            self.memmap_dir,
            self.frame_stack,
        )
        mask_size = (height, width) if self.store_masks else None
        self._sampler = BatchSampler(
            self._storage, self._rings, self.n_steps, self.gamma, self.horizon, mask_size, prefetch, seed
        )
        self._sb3_rows_cache: tuple[tuple[int, int], np.ndarray] | None = None

    @property
    def device(self) -> th.device:
        """The training device; setting it (SB3's ``load_replay_buffer`` does) moves an ``"auto"`` storage."""
        return self._device

    @device.setter
    def device(self, device: th.device | str) -> None:
        self._device = get_device(device)
        if "_storage" not in self.__dict__:  # BaseBuffer.__init__ sets the device before the storage exists
            return
        storage = self._storage.choose_device(self.storage_request, self._device)
        if not self._storage.allocated:
            self.storage_device = storage
        elif storage != self.storage_device:
            self._sampler.drop_pending()
            self._storage.move(storage, self._rings.has_step_rows)
            self.storage_device = storage

    @property
    def prefetch(self) -> bool | None:
        """See ``prefetch`` in the class docstring."""
        return self._sampler.prefetch

    @prefetch.setter
    def prefetch(self, prefetch: bool | None) -> None:
        self._sampler.prefetch = prefetch

    @property
    def nbytes(self) -> int:
        """Bytes the whole capacity takes once allocated (memory-mapped frames included)."""
        rings = self._rings
        host = rings.has_step_rows.nbytes + rings.head.nbytes + rings.episode_open.nbytes + rings.last_obs.nbytes
        return sum(self._storage.bytes_needed()) + host

    def size(self) -> int:
        return self._rings.n_transitions

    def reset(self) -> None:
        """Forget everything stored (the storage stays allocated)."""
        self._sampler.drop_pending()
        super().reset()
        self._rings.reset()
        if self._storage.allocated:
            self._storage.step_flags.zero_()

    def seed(self, seed: int) -> None:
        """Restart the sampling stream from ``seed`` (a prefetched batch is dropped)."""
        self._sampler.seed(seed)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of every env, as SB3's ``_store_transition`` calls it; a refused call stores nothing."""
        expected_shape = (self.n_envs, *self.obs_shape)
        obs, next_obs = np.asarray(obs), np.asarray(next_obs)
        for name, array in (("obs", obs), ("next_obs", next_obs)):
            if array.shape != expected_shape:
                raise ValueError(
                    f"SequenceReplayBuffer.add expects {name} of shape {expected_shape}, got {array.shape}"
                )
        action = np.asarray(action, dtype=np.float32).reshape(self.n_envs, self.action_dim)
        reward = np.asarray(reward, dtype=np.float32).reshape(self.n_envs)
        done = np.asarray(done, dtype=bool).reshape(self.n_envs)
        rings, storage = self._rings, self._storage
        rings.check_step(obs, next_obs, action, reward)
        masks = rings.step_masks(infos, self.frame_shape[1:]) if self.store_masks else None
        truncated = np.array(
            [self.handle_timeout_termination and info.get("TimeLimit.truncated", False) for info in infos], dtype=bool
        )
        if not storage.allocated:
            storage.allocate(self.storage_device, rings.has_step_rows)
            self.storage_device = storage.device
        self._sampler.wait_for_prefetch()

        placement = rings.place(obs, next_obs, done)
        packed = None
        if masks is not None:  # a new episode stores the masks of its first observation's frames too
            new = [masks[env] if placement.started[env] else masks[env, -1:] for env in range(self.n_envs)]
            packed = np.packbits(np.concatenate(new).reshape(len(placement.frame_rows), -1), axis=1)
        storage.write_frames(placement.frame_rows, np.stack(placement.frames), packed)
        storage.write_steps(placement.step_rows, actions=action, rewards=reward, dones=done, timeouts=truncated)
        storage.update_step_flags(placement.touched_rows, rings.has_step_rows)
        self.pos = (self.pos + 1) % self.buffer_size
        self.full = self.full or self.pos == 0

    def sample(  # type: ignore[override]  # SB3's ReplayBufferSamples, a NamedTuple, cannot be extended
        self, batch_size: int, env: VecNormalize | None = None
    ) -> SequenceReplayBufferSamples:
        """Draw ``batch_size`` transitions uniformly; frame tensors are reused two calls later (docs/buffer.md)."""
        if self._rings.n_transitions == 0:
            raise ValueError("SequenceReplayBuffer.sample expects a buffer with at least one transition, got none")
        if batch_size < 1:
            raise ValueError(f"SequenceReplayBuffer.sample expects batch_size >= 1, got {batch_size}")
        if env is not None and getattr(env, "norm_obs", False):
            raise ValueError("SequenceReplayBuffer expects uint8 images that are not normalised (norm_obs=False)")
        return self._sampler.sample(batch_size, self.device, env)

    def side_sampler(self, seed: int) -> BatchSampler:
        """A sampler with a generator of its own and no prefetch, which leaves :meth:`sample`'s draws as they were."""
        mask_size = self._sampler.mask_size
        return BatchSampler(self._storage, self._rings, self.n_steps, self.gamma, self.horizon, mask_size, False, seed)

    def _sb3_rows(self) -> np.ndarray:
        key = (self._rings.version, self.pos)
        if self._sb3_rows_cache is None or self._sb3_rows_cache[0] != key:
            self._sb3_rows_cache = (key, sb3_rows(self._rings, self.pos))
        return self._sb3_rows_cache[1]

    @property
    def observations(self) -> StackedFrameView:  # type: ignore[override]
        """SB3's observations: a read-only view gathered when indexed."""
        return StackedFrameView(self._storage, self._sb3_rows(), self.buffer_size, self.frame_stack, offset=0)

    @property
    def next_observations(self) -> StackedFrameView:  # type: ignore[override]
        """SB3's next observations: a read-only view gathered when indexed."""
        return StackedFrameView(self._storage, self._sb3_rows(), self.buffer_size, self.frame_stack, offset=1)

    actions = step_array_property("actions")
    rewards = step_array_property("rewards")
    dones = step_array_property("dones")  # time limits included
    timeouts = step_array_property("timeouts")

    def __getstate__(self) -> dict[str, Any]:
        return persistence.buffer_state(self)

    def __setstate__(self, state: dict[str, Any]) -> None:
        persistence.restore_buffer(self, state)
