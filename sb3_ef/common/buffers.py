"""Frame-deduplicating replay buffer that samples RL transitions together with Ego-Foresight windows.

Stacked image observations share all but one frame with their neighbours, so each frame is stored once in a
per-environment ring of frames. An episode occupies ``frame_stack`` frames for its first (stacked) observation,
then one frame per step (the newest frame of the next observation, terminal observations included). Stacked
observations are rebuilt at sample time from consecutive frames, so they equal what the env emitted, episode
starts included, whatever padding the env used. See docs/buffer.md for the layout and the rules.
"""

from __future__ import annotations

import os
import tempfile
import warnings
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, ReplayBuffer
from stable_baselines3.common.vec_env import VecNormalize

try:  # optional, as in SB3: only used to warn when the buffer cannot fit in memory
    import psutil
except ImportError:  # pragma: no cover
    psutil = None


class SequenceReplayBufferSamples(NamedTuple):
    """One batch: an n-step RL transition plus the Ego-Foresight window that starts at the same step."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor
    future_actions: th.Tensor
    future_frames: th.Tensor
    future_rewards: th.Tensor
    future_mask: th.Tensor


def _check_observation_space(observation_space: spaces.Space, frame_channels: int) -> int:
    """Return the frame stack k of a uint8 ``Box(0, 255, (frame_channels * k, h, w))``, or raise."""
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
    """Replay buffer for stacked uint8 image observations that keeps each frame once.

    Usable as SB3's ``replay_buffer_class`` (it subclasses ``ReplayBuffer`` so that SB3 accepts it when loading,
    but allocates none of ``ReplayBuffer``'s observation arrays) and directly by the standalone TD-MPC2.

    :param buffer_size: capacity in frames, shared equally by the ``n_envs`` environments (as SB3 splits it). An
        episode of T steps uses T + frame_stack frames.
    :param observation_space: ``Box(0, 255, (frame_channels * k, h, w), uint8)``, frames stacked oldest first.
    :param action_space: a ``Box`` action space.
    :param device: torch device of the sampled tensors.
    :param n_envs: number of parallel environments.
    :param optimize_memory_usage: must be False: frames are always stored once (SB3's flag would make SB3 write
        into arrays this buffer does not have).
    :param handle_timeout_termination: when True, ``infos[i]["TimeLimit.truncated"]`` marks a time limit,
        which bootstraps instead of terminating.
    :param n_steps: number of steps summed in the n-step return.
    :param gamma: discount of the n-step return.
    :param horizon: length H of the Ego-Foresight window (future actions, frames, rewards).
    :param frame_channels: channels of one frame (3 for RGB).
    :param memmap_dir: when set, the frames live in an unnamed temporary file in this folder (``np.memmap``), so
        a large buffer need not fit in RAM. Pickling (``save_replay_buffer``) copies the frames into the pickle.
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
    ):
        frame_stack = _check_observation_space(observation_space, frame_channels)
        if not isinstance(action_space, spaces.Box):
            raise ValueError(f"SequenceReplayBuffer expects a Box action space, got {action_space}")
        if optimize_memory_usage:
            raise ValueError(
                "SequenceReplayBuffer expects optimize_memory_usage=False (it always stores each frame once), got True"
            )
        if n_steps < 1:
            raise ValueError(f"SequenceReplayBuffer expects n_steps >= 1, got {n_steps}")
        if horizon < 1:
            raise ValueError(f"SequenceReplayBuffer expects horizon >= 1, got {horizon}")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"SequenceReplayBuffer expects 0 <= gamma <= 1, got {gamma}")
        if n_envs < 1:
            raise ValueError(f"SequenceReplayBuffer expects n_envs >= 1, got {n_envs}")
        capacity = buffer_size // n_envs
        if capacity <= horizon + frame_stack:
            raise ValueError(
                f"SequenceReplayBuffer expects buffer_size // n_envs > horizon + frame_stack = {horizon + frame_stack} "
                f"frames per env (one window and its context), got {buffer_size} // {n_envs} = {capacity}"
            )
        # ReplayBuffer.__init__ would allocate full observation arrays: set up only the base buffer.
        BaseBuffer.__init__(self, buffer_size, observation_space, action_space, device, n_envs=n_envs)
        self.buffer_size = capacity
        self.optimize_memory_usage = False
        self.handle_timeout_termination = handle_timeout_termination
        self.n_steps = n_steps
        self.gamma = gamma
        self.horizon = horizon
        self.frame_channels = frame_channels
        self.frame_stack = frame_stack
        self.frame_shape = (frame_channels, *observation_space.shape[1:])
        self.memmap_dir = None if memmap_dir is None else os.fspath(memmap_dir)

        self._frames = self._allocate_frames()
        self._actions = np.zeros((n_envs, capacity, self.action_dim), dtype=np.float32)
        self._rewards = np.zeros((n_envs, capacity), dtype=np.float32)
        self._terminals = np.zeros((n_envs, capacity), dtype=bool)
        # _has_step[e, s]: a transition starts at the observation whose newest frame is in slot s, and all its
        # context frames are still stored. An episode's steps form one run of step slots, closed by its last
        # frame (and the newest frame of the ring), which never carries a step: a run never crosses episodes.
        self._has_step = np.zeros((n_envs, capacity), dtype=bool)
        self._head = np.full(n_envs, -1, dtype=np.int64)  # absolute index of the newest frame per env
        self._episode_open = np.zeros(n_envs, dtype=bool)  # the env's last step did not end its episode
        self._n_transitions = 0

        if psutil is not None and self.memmap_dir is None and self.nbytes > psutil.virtual_memory().available:
            warnings.warn(
                f"SequenceReplayBuffer needs {self.nbytes / 1e9:.2f} GB but only "
                f"{psutil.virtual_memory().available / 1e9:.2f} GB are available: consider memmap_dir"
            )

    def _allocate_frames(self) -> np.ndarray:
        """Zeroed frame storage, in RAM or in an unnamed temporary file under ``memmap_dir``."""
        shape = (self.n_envs, self.buffer_size, *self.frame_shape)
        if self.memmap_dir is None:
            return np.zeros(shape, dtype=np.uint8)
        os.makedirs(self.memmap_dir, exist_ok=True)
        # The file has no name and the mapping keeps it alive: it is freed with the array, even after a crash.
        with tempfile.TemporaryFile(dir=self.memmap_dir, prefix="sb3_ef_frames_") as file:
            return np.memmap(file, dtype=np.uint8, mode="w+", shape=shape)

    @property
    def nbytes(self) -> int:
        """Bytes allocated for the whole capacity (frames on disk included when memory-mapped)."""
        arrays = (self._frames, self._actions, self._rewards, self._terminals, self._has_step)
        return sum(array.nbytes for array in arrays) + self._head.nbytes + self._episode_open.nbytes

    def size(self) -> int:
        """Number of transitions that can be sampled."""
        return self._n_transitions

    def reset(self) -> None:
        """Forget everything stored (the storage stays allocated)."""
        super().reset()
        self._has_step[:] = False
        self._head[:] = -1
        self._episode_open[:] = False
        self._n_transitions = 0

    # ------------------------------------------------------------------ writing
    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """Store one step of every env, as SB3's ``_store_transition`` calls it.

        ``next_obs[i]`` is the terminal observation when env ``i`` finished. An ``obs`` that does not continue the
        env's stored episode (e.g. the env was reset by a new ``learn()`` call) starts a new episode and leaves the
        previous one cut, which bootstraps like a time limit.
        """
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
        channels = self.frame_channels
        for env in range(self.n_envs):
            if not np.array_equal(next_obs[env, :-channels], obs[env, channels:]):
                raise ValueError(
                    "SequenceReplayBuffer expects frame stacks that slide by one frame per step "
                    f"(next_obs[{env}][:-{channels}] == obs[{env}][{channels}:]), got stacks that differ"
                )
            if not (self._episode_open[env] and np.array_equal(obs[env], self._stack(env, self._head[env]))):
                for frame in obs[env].reshape(self.frame_stack, *self.frame_shape):
                    self._write_frame(env, frame)
            slot = self._head[env] % self.buffer_size
            truncated = self.handle_timeout_termination and infos[env].get("TimeLimit.truncated", False)
            self._actions[env, slot] = action[env]
            self._rewards[env, slot] = reward[env]
            self._terminals[env, slot] = done[env] and not truncated
            self._has_step[env, slot] = True
            self._n_transitions += 1
            self._write_frame(env, next_obs[env, -channels:])
            self._episode_open[env] = not done[env]

    def _stack(self, env: int, newest: int) -> np.ndarray:
        """The stacked observation whose newest frame has absolute index ``newest`` in ``env``'s ring."""
        slots = np.arange(newest - self.frame_stack + 1, newest + 1) % self.buffer_size
        return self._frames[env, slots].reshape(self.obs_shape)

    def _write_frame(self, env: int, frame: np.ndarray) -> None:
        """Append a frame to ``env``'s ring; an overwritten frame invalidates every step that reads it as context."""
        newest = self._head[env] + 1
        slot = newest % self.buffer_size
        if newest >= self.buffer_size:
            # The steps whose stacked observation holds the overwritten frame sit in this slot and the next k - 1
            # (a later episode's first step sits at least k slots further). They are never sampled again.
            readers = np.arange(slot, slot + self.frame_stack) % self.buffer_size
            self._n_transitions -= int(self._has_step[env, readers].sum())
            self._has_step[env, readers] = False
        self._frames[env, slot] = frame
        self._head[env] = newest

    # ----------------------------------------------------------------- sampling
    def sample(self, batch_size: int, env: VecNormalize | None = None) -> SequenceReplayBufferSamples:
        """Draw ``batch_size`` transitions uniformly over all stored ones (with replacement)."""
        if self._n_transitions == 0:
            raise ValueError("SequenceReplayBuffer.sample expects a buffer with at least one transition, got none")
        if batch_size < 1:
            raise ValueError(f"SequenceReplayBuffer.sample expects batch_size >= 1, got {batch_size}")
        # Slots [0, filled) of each env's ring are written; draw uniformly among them and keep step slots.
        filled = np.minimum(self._head + 1, self.buffer_size)
        ends = np.cumsum(filled)
        chosen: list[np.ndarray] = []
        missing = batch_size
        while missing > 0:
            flat = np.random.randint(0, ends[-1], size=2 * missing + 8)
            envs = np.searchsorted(ends, flat, side="right")
            slots = flat - (ends[envs] - filled[envs])
            inds = (envs * self.buffer_size + slots)[self._has_step[envs, slots]][:missing]
            chosen.append(inds)
            missing -= len(inds)
        return self._get_samples(np.concatenate(chosen), env=env)

    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> SequenceReplayBufferSamples:
        """Gather transitions and windows for flat indices ``env * buffer_size + slot`` of step slots."""
        if env is not None and getattr(env, "norm_obs", False):
            raise ValueError("SequenceReplayBuffer expects uint8 images that are not normalised (norm_obs=False)")
        capacity, stack = self.buffer_size, self.frame_stack
        envs, slots = np.divmod(batch_inds, capacity)
        head = self._head[envs]
        start = head - (head - slots) % capacity  # absolute index of each sample's newest obs frame
        span = max(self.n_steps, self.horizon)
        steps = start[:, None] + np.arange(span)  # absolute index of steps t .. t + span - 1
        step_slots = steps % capacity
        env_col = envs[:, None]
        valid = np.logical_and.accumulate(self._has_step[env_col, step_slots], axis=1)  # inside the episode
        step_rewards = self._normalize_reward(self._rewards[env_col, step_slots], env) * valid

        n_valid = valid[:, : self.n_steps].sum(axis=1)  # m >= 1 steps summed
        discounts = self.gamma ** np.arange(self.n_steps, dtype=np.float32)
        returns = (step_rewards[:, : self.n_steps] * discounts).sum(axis=1, keepdims=True)
        last_slots = step_slots[np.arange(len(batch_inds)), n_valid - 1]
        dones = self._terminals[envs, last_slots].astype(np.float32)[:, None]

        context = np.arange(1 - stack, 1)
        observations = self._frames[env_col, (start[:, None] + context) % capacity]
        next_observations = self._frames[env_col, ((start + n_valid)[:, None] + context) % capacity]
        window = valid[:, : self.horizon]
        future_frames = self._frames[env_col, (step_slots[:, : self.horizon] + 1) % capacity]
        future_frames[~window] = 0
        future_actions = self._actions[env_col, step_slots[:, : self.horizon]] * window[..., None]

        batch = len(batch_inds)
        data = (
            observations.reshape(batch, *self.obs_shape),
            self._actions[envs, slots],
            next_observations.reshape(batch, *self.obs_shape),
            dones,
            returns.astype(np.float32),
            (self.gamma ** n_valid.astype(np.float32))[:, None],
            future_actions,
            future_frames,
            step_rewards[:, : self.horizon].astype(np.float32),
            window,
        )
        return SequenceReplayBufferSamples(*(self.to_torch(array, copy=False) for array in data))

    # ------------------------------------------------------------- save / load
    def __getstate__(self) -> dict[str, Any]:
        """Pickle the written frames themselves (memory-mapped or not), so a saved buffer is self-contained."""
        state = self.__dict__.copy()
        written = int(min(self._head.max() + 1, self.buffer_size))
        state["_frames"] = [np.asarray(self._frames[env, :written]) for env in range(self.n_envs)]  # no copies
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Rebuild the frame storage (a fresh memmap file when ``memmap_dir`` is set) and copy the frames in."""
        frames = state.pop("_frames")
        self.__dict__.update(state)
        self._frames = self._allocate_frames()
        for env, env_frames in enumerate(frames):
            self._frames[env, : len(env_frames)] = env_frames
