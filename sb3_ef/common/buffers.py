"""Frame-deduplicating replay buffer that samples RL transitions together with Ego-Foresight windows.

Stacked image observations share all but one frame with their neighbours, so each frame is stored once in a
per-environment ring of frames. An episode occupies ``frame_stack`` frames for its first (stacked) observation,
then one frame per step (the newest frame of the next observation, terminal observations included). Stacked
observations are rebuilt at sample time from consecutive frames, so they equal what the env emitted, episode
starts included, whatever padding the env used.

Frames and per-step arrays are torch tensors on a storage device (host memory or the training GPU), and sampling
gathers there with indices drawn by the buffer's own generator. The storage is allocated (and its size checked
against the memory available) at the first ``add()``, so a model loaded only to act never reserves it. See
docs/buffer.md for the layout and the rules.
"""

from __future__ import annotations

import os
import shutil
import tempfile
import warnings
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import BaseBuffer, ReplayBuffer
from stable_baselines3.common.utils import get_device
from stable_baselines3.common.vec_env import VecNormalize

# "auto" keeps this share of the GPU's total memory (at least MIN_DEVICE_MARGIN) free for the model and the update.
DEVICE_MARGIN_FRACTION = 0.25
MIN_DEVICE_MARGIN = 4 * 2**30
_SEED_SALT = 0x5EB3EF  # keeps the buffer's stream apart from torch's own stream of the same seed


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


def available_host_memory() -> int | None:
    """Bytes of RAM the kernel reports as available (``MemAvailable``), or None where it does not say."""
    try:
        import psutil  # optional, as in SB3

        return int(psutil.virtual_memory().available)
    except ImportError:
        pass
    try:
        with open("/proc/meminfo") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def _storage_request(storage_device: str | th.device) -> str | th.device:
    """``"auto"`` or a torch device, refused when it names a CUDA device this machine does not have."""
    if storage_device == "auto":
        return "auto"
    try:
        device = th.device(storage_device)
    except (RuntimeError, TypeError) as error:
        raise ValueError(
            "SequenceReplayBuffer expects storage_device 'auto', 'cpu', 'cuda' or a torch.device, "
            f"got {storage_device!r}"
        ) from error
    if device.type == "cuda" and not th.cuda.is_available():
        raise ValueError(f"SequenceReplayBuffer storage_device={storage_device!r} needs CUDA, which is not available")
    return device


@dataclass
class _Gathered:
    """What the storage device gathers for one batch; the reward sums are finished at hand-out."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    future_actions: th.Tensor
    future_frames: th.Tensor
    step_rewards: th.Tensor  # (B, max(n_steps, horizon)) raw rewards, zero outside the episode
    valid: th.Tensor  # (B, max(n_steps, horizon)) step t + i taken inside the episode
    copied: Any = None  # CUDA event: the batch has reached the training device


class _OutputSlot:
    """Reused frame outputs of one batch: on the storage device, plus a pinned copy target on the training device."""

    def __init__(self) -> None:
        self.frames: tuple[th.Tensor, ...] = ()
        self.device_frames: tuple[th.Tensor, ...] = ()
        self.copied: Any = None  # CUDA event recorded after this slot's last host-to-device copy

    def frame_outputs(self, shapes: list[tuple[int, ...]], storage: th.device, pin: bool) -> tuple[th.Tensor, ...]:
        if [tuple(frames.shape) for frames in self.frames] != shapes or self.frames[0].device != storage:
            self.frames = tuple(th.empty(shape, dtype=th.uint8, device=storage, pin_memory=pin) for shape in shapes)
        elif self.copied is not None:
            self.copied.synchronize()  # the previous batch of this slot has left the pinned memory
        return self.frames

    def device_outputs(self, device: th.device) -> tuple[th.Tensor, ...]:
        shapes = [tuple(frames.shape) for frames in self.frames]
        if [tuple(frames.shape) for frames in self.device_frames] != shapes or self.device_frames[0].device != device:
            self.device_frames = tuple(th.empty(shape, dtype=th.uint8, device=device) for shape in shapes)
        return self.device_frames


@dataclass
class _Pending:
    """A batch drawn at the previous hand-out and being gathered in the background."""

    batch_size: int
    indices: np.ndarray  # (2, B): env and absolute index of each sample's newest observation frame
    slot: int
    future: Future | None = None


class SequenceReplayBuffer(ReplayBuffer):
    """Replay buffer for stacked uint8 image observations that keeps each frame once.

    Usable as SB3's ``replay_buffer_class`` (it subclasses ``ReplayBuffer`` so that SB3 accepts it when loading,
    but allocates none of ``ReplayBuffer``'s observation arrays) and directly by the standalone TD-MPC2.

    :param buffer_size: capacity in frames, shared equally by the ``n_envs`` environments (as SB3 splits it). An
        episode of T steps uses T + frame_stack frames.
    :param observation_space: ``Box(0, 255, (frame_channels * k, h, w), uint8)``, frames stacked oldest first.
    :param action_space: a ``Box`` action space.
    :param device: torch device of the sampled tensors (the training device).
    :param n_envs: number of parallel environments.
    :param optimize_memory_usage: must be False: frames are always stored once (SB3's flag would make SB3 write
        into arrays this buffer does not have).
    :param handle_timeout_termination: when True, ``infos[i]["TimeLimit.truncated"]`` marks a time limit,
        which bootstraps instead of terminating.
    :param n_steps: number of steps summed in the n-step return.
    :param gamma: discount of the n-step return.
    :param horizon: length H of the Ego-Foresight window (future actions, frames, rewards).
    :param frame_channels: channels of one frame (3 for RGB).
    :param memmap_dir: when set, the frames live in an unnamed temporary file in this folder (``np.memmap``, host
        storage), so a large buffer need not fit in RAM. Pickling (``save_replay_buffer``) copies the frames into
        the pickle.
    :param storage_device: where frames and per-step arrays live and are gathered: ``"cpu"`` (host memory), a CUDA
        device (``"cuda"``, a ``torch.device``), or ``"auto"``: the training device when the whole buffer plus a
        margin (a quarter of the GPU's memory, at least 4 GiB) fits its free memory, else host memory. The storage
        is allocated at the first ``add()``, which raises ``MemoryError`` before storing anything when it does not
        fit; host memory is zeroed lazily by the OS (pages are committed as frames are written).
    :param prefetch: gather the next batch in a background thread while the caller uses this one. ``None``: on
        when the training device is CUDA and the storage is host memory.
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
        request = _storage_request(storage_device)
        if memmap_dir is not None and request != "auto" and request.type != "cpu":
            raise ValueError(
                f"SequenceReplayBuffer keeps memory-mapped frames in host memory: memmap_dir expects "
                f"storage_device 'cpu' or 'auto', got {storage_device!r}"
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
        self.storage_request = request
        self.prefetch = prefetch
        # SB3's set_random_seed sets torch's initial seed to the model's seed: seeded runs draw the same batches, and
        # nothing else (the env code's NumPy draws, the networks' initialisation) moves this stream or is moved by it.
        self._rng = np.random.default_rng((th.initial_seed(), _SEED_SALT))

        # Host-side bookkeeping. _has_step_rows[e * capacity + s]: a transition starts at the observation whose newest
        # frame is in slot s of env e, and all its context frames are still stored (the last row, always False,
        # pads masked reads). An episode's steps form one run of step slots, closed by its last frame (and the
        # newest frame of the ring), which never carries a step: a run never crosses episodes.
        self._has_step_rows = np.zeros(n_envs * capacity + 1, dtype=bool)
        self._head = np.full(n_envs, -1, dtype=np.int64)  # absolute index of the newest frame per env
        self._episode_open = np.zeros(n_envs, dtype=bool)  # the env's last step did not end its episode
        self._last_obs = np.zeros((n_envs, *self.obs_shape), dtype=np.uint8)  # the stack whose newest frame is head
        self._n_transitions = 0
        self._n_adds = 0
        # Chosen now, allocated at the first add(): SB3's load rebuilds this buffer for models loaded only to act.
        self.storage_device = self._resolve_storage()
        self._init_runtime()

    # ----------------------------------------------------------------- storage
    @property
    def device(self) -> th.device:
        """The training device: sampled tensors land here. Setting it (SB3 does after ``load_replay_buffer``)
        moves an ``"auto"`` storage to where it now belongs."""
        return self._device

    @device.setter
    def device(self, device: th.device | str) -> None:
        self._device = get_device(device)
        if "storage_device" not in self.__dict__:  # BaseBuffer.__init__ sets the device before the storage exists
            return
        storage = self._resolve_storage()
        if not self._allocated:
            self.storage_device = storage
        elif storage != self.storage_device:
            self._move_storage(storage)

    @property
    def _allocated(self) -> bool:
        """The storage exists (it is allocated at the first ``add()``, or when a pickle with frames is loaded)."""
        return "_frames" in self.__dict__

    @property
    def _has_step(self) -> np.ndarray:
        """``(n_envs, capacity)`` view of the step flags."""
        return self._has_step_rows[:-1].reshape(self.n_envs, self.buffer_size)

    def _storage_bytes(self) -> tuple[int, int]:
        """Bytes of the frames and of the per-step arrays (one extra zero row each) on the storage device."""
        rows = self.n_envs * self.buffer_size + 1
        return rows * int(np.prod(self.frame_shape)), rows * (4 * self.action_dim + 4 + 1 + 1)

    @property
    def nbytes(self) -> int:
        """Bytes the whole capacity takes once allocated at the first ``add()`` (frames on disk included when
        memory-mapped)."""
        host = self._has_step_rows.nbytes + self._head.nbytes + self._episode_open.nbytes + self._last_obs.nbytes
        return sum(self._storage_bytes()) + host

    def _resolve_storage(self) -> th.device:
        """The storage device ``storage_request`` names on this machine (see the class docstring)."""
        request = self.storage_request
        if request != "auto":
            if request.type == "cuda" and not th.cuda.is_available():  # a buffer loaded on a machine without CUDA
                warnings.warn(f"SequenceReplayBuffer storage_device={request} needs CUDA: frames stay in host memory")
                return th.device("cpu")
            return _normalize_device(request)
        training = _normalize_device(self.device)
        if self.memmap_dir is None and training.type == "cuda":
            free, total = th.cuda.mem_get_info(training)
            if sum(self._storage_bytes()) + max(MIN_DEVICE_MARGIN, DEVICE_MARGIN_FRACTION * total) <= free:
                return training
        return th.device("cpu")

    def _check_memory(self, storage: th.device) -> None:
        """Raise before allocating when the storage cannot hold the buffer, naming the ways out."""
        frame_bytes, step_bytes = self._storage_bytes()
        ways_out = [
            f"a smaller buffer_size (an episode of T steps takes T + {self.frame_stack} frames; to go on training a "
            "saved model, Model.load(path, buffer_size=...))"
        ]
        if storage.type == "cuda":
            needed, available, where = frame_bytes + step_bytes, th.cuda.mem_get_info(storage)[0], f"{storage} memory"
            ways_out.append("storage_device='cpu' (host memory; batches are copied to the GPU)")
        elif self.memmap_dir is not None:
            os.makedirs(self.memmap_dir, exist_ok=True)
            needed, available = frame_bytes, shutil.disk_usage(self.memmap_dir).free
            where = f"disk space in memmap_dir={self.memmap_dir}"
            ways_out.append("a memmap_dir on a larger disk")
        else:
            needed, available, where = frame_bytes + step_bytes, available_host_memory(), "RAM"
            ways_out.append(
                f"memmap_dir=<a folder on a disk with {frame_bytes / 1e9:.1f} GB free> (frames in a file, read "
                "through the page cache)"
            )
        if available is None or needed <= available:
            return
        raise MemoryError(
            f"SequenceReplayBuffer needs {needed / 1e9:.2f} GB ({self.n_envs * self.buffer_size} frames of "
            f"{self.frame_shape} uint8 and their step data) but only {available / 1e9:.2f} GB of {where} are "
            f"available. Ways out: {'; or '.join(ways_out)}."
        )

    def _allocate_storage(self, storage: th.device) -> None:
        """Zeroed frames (in RAM, in an unnamed temporary file under ``memmap_dir``, or on a GPU) and step arrays.

        Host arrays come from ``np.zeros`` (calloc): the OS commits their pages when they are first written, so RAM
        grows with the frames stored rather than with the capacity (``th.zeros`` would write every page now)."""
        self._check_memory(storage)
        rows = self.n_envs * self.buffer_size + 1  # the last row stays zero: masked reads point at it
        self._frame_map = None
        if self.memmap_dir is not None:
            # The file has no name and the mapping keeps it alive: it is freed with the array, even after a crash.
            with tempfile.TemporaryFile(dir=self.memmap_dir, prefix="sb3_ef_frames_") as file:
                self._frame_map = np.memmap(file, dtype=np.uint8, mode="w+", shape=(rows, *self.frame_shape))
            self._frames = th.from_numpy(self._frame_map)
        else:
            self._frames = _zeros((rows, *self.frame_shape), th.uint8, storage)
        self._actions = _zeros((rows, self.action_dim), th.float32, storage)
        self._rewards = _zeros((rows,), th.float32, storage)
        self._terminals = _zeros((rows,), th.bool, storage)
        self.storage_device = storage
        self._share_step_flags()

    def _share_step_flags(self) -> None:
        """Step flags on the storage device: the host array itself in host storage, a copy on a GPU."""
        flags = th.from_numpy(self._has_step_rows)
        self._step_flags = flags if self.storage_device.type == "cpu" else flags.to(self.storage_device)

    def _move_storage(self, storage: th.device) -> None:
        """Move every stored tensor to ``storage`` (the frames are copied once)."""
        self._drop_pending()
        self._check_memory(storage)
        for name in ("_frames", "_actions", "_rewards", "_terminals"):
            setattr(self, name, getattr(self, name).to(storage))
        self.storage_device = storage
        self._share_step_flags()

    def _init_runtime(self) -> None:
        """State that is rebuilt rather than pickled: reused outputs, the prefetch thread and its batch."""
        self._slots = [_OutputSlot() for _ in range(3)]
        self._next_slot = 0
        self._pending: _Pending | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._copy_stream: th.cuda.Stream | None = None

    def size(self) -> int:
        """Number of transitions that can be sampled."""
        return self._n_transitions

    def reset(self) -> None:
        """Forget everything stored (the storage stays allocated)."""
        self._drop_pending()
        super().reset()
        self._has_step_rows[:] = False
        if self._allocated:
            self._step_flags.zero_()
        self._head[:] = -1
        self._episode_open[:] = False
        self._n_transitions = 0

    def seed(self, seed: int) -> None:
        """Restart the sampling stream from ``seed`` (a prefetched batch is dropped)."""
        self._drop_pending()
        self._rng = np.random.default_rng((seed, _SEED_SALT))

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
        previous one cut, which bootstraps like a time limit. A refused call stores nothing.
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
        self._check_step(obs, next_obs, action, reward)
        if not self._allocated:
            self._allocate_storage(self.storage_device)
        self._wait_for_prefetch()

        channels, capacity = self.frame_channels, self.buffer_size
        frame_rows: list[int] = []
        frames: list[np.ndarray] = []
        cleared: list[np.ndarray] = []
        step_rows = np.empty(self.n_envs, dtype=np.int64)
        for env in range(self.n_envs):
            if not (self._episode_open[env] and np.array_equal(obs[env], self._last_obs[env])):
                for frame in obs[env].reshape(self.frame_stack, *self.frame_shape):
                    frame_rows.append(self._advance(env, cleared))
                    frames.append(frame)
            step_rows[env] = env * capacity + self._head[env] % capacity
            self._has_step_rows[step_rows[env]] = True
            self._n_transitions += 1
            frame_rows.append(self._advance(env, cleared))
            frames.append(next_obs[env, -channels:])
            self._last_obs[env] = next_obs[env]
            self._episode_open[env] = not done[env]
        truncated = np.array(
            [self.handle_timeout_termination and info.get("TimeLimit.truncated", False) for info in infos]
        )
        _write_rows(self._frames, frame_rows, np.stack(frames))
        _write_rows(self._actions, step_rows, action)
        _write_rows(self._rewards, step_rows, reward)
        _write_rows(self._terminals, step_rows, done & ~truncated)
        if self.storage_device.type != "cpu":  # the flags have a copy on the GPU
            touched = np.unique(np.concatenate([step_rows, *cleared]))
            _write_rows(self._step_flags, touched, self._has_step_rows[touched])
        self._n_adds += 1

    def _check_step(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray) -> None:
        """Refuse non-finite values and stacks that do not slide, before anything is written."""
        checked = {"rewards": reward, "actions": action}
        if np.issubdtype(obs.dtype, np.floating):  # uint8 frames are finite by construction
            checked.update(obs=obs, next_obs=next_obs)
        for name, values in checked.items():
            finite = np.isfinite(values.reshape(self.n_envs, -1))
            if not finite.all():
                env = int(np.argmin(finite.all(axis=1)))
                value = (
                    values[env] if name != "obs" and name != "next_obs" else values[env].reshape(-1)[~finite[env]][0]
                )
                raise ValueError(
                    f"SequenceReplayBuffer.add expects finite {name}, got {value} for env {env} at step "
                    f"{self._n_adds} (add() calls so far); nothing of this call was stored"
                )
        channels = self.frame_channels
        for env in range(self.n_envs):
            if not np.array_equal(next_obs[env, :-channels], obs[env, channels:]):
                raise ValueError(
                    "SequenceReplayBuffer expects frame stacks that slide by one frame per step "
                    f"(next_obs[{env}][:-{channels}] == obs[{env}][{channels}:]), got stacks that differ"
                )

    def _advance(self, env: int, cleared: list[np.ndarray]) -> int:
        """Take the next slot of ``env``'s ring and return its row; overwriting a frame invalidates every step
        that reads it as context (those rows are appended to ``cleared``)."""
        newest = self._head[env] + 1
        slot = newest % self.buffer_size
        if newest >= self.buffer_size:
            # The steps whose stacked observation holds the overwritten frame sit in this slot and the next k - 1
            # (a later episode's first step sits at least k slots further). They are never sampled again.
            readers = env * self.buffer_size + np.arange(slot, slot + self.frame_stack) % self.buffer_size
            self._n_transitions -= int(self._has_step_rows[readers].sum())
            self._has_step_rows[readers] = False
            cleared.append(readers)
        self._head[env] = newest
        return env * self.buffer_size + slot

    # ----------------------------------------------------------------- sampling
    def sample(self, batch_size: int, env: VecNormalize | None = None) -> SequenceReplayBufferSamples:
        """Draw ``batch_size`` transitions uniformly over all stored ones (with replacement).

        The frame tensors of a batch are reused: a batch stays valid until the second call to ``sample()`` after
        the one that returned it (clone what you keep longer). With prefetch, the batch was drawn when the previous
        one was handed out (docs/buffer.md says how stale it may be).
        """
        if self._n_transitions == 0:
            raise ValueError("SequenceReplayBuffer.sample expects a buffer with at least one transition, got none")
        if batch_size < 1:
            raise ValueError(f"SequenceReplayBuffer.sample expects batch_size >= 1, got {batch_size}")
        if env is not None and getattr(env, "norm_obs", False):
            raise ValueError("SequenceReplayBuffer expects uint8 images that are not normalised (norm_obs=False)")
        released = self._release_event()
        pending, self._pending = self._pending, None
        gathered = None
        if pending is not None:
            gathered = self._take_pending(pending, released) if pending.batch_size == batch_size else None
            if gathered is None:
                self._wait(pending)
                self._next_slot = pending.slot  # reuse its outputs, so that no handed-out batch is overwritten
        if gathered is None:
            gathered = self._gather(self._draw(batch_size), self._take_slot(), released)
        if self._prefetching():
            indices, slot = self._draw(batch_size), self._take_slot()
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sb3_ef_prefetch")
            self._pending = _Pending(
                batch_size, indices, slot, self._executor.submit(self._gather, indices, slot, released)
            )
        return self._finish(gathered, env)

    def _transfers_to_gpu(self) -> bool:
        """Batches are gathered in host memory and copied to a CUDA training device."""
        return self.storage_device.type == "cpu" and self.device.type == "cuda"

    def _prefetching(self) -> bool:
        return self.prefetch if self.prefetch is not None else self._transfers_to_gpu()

    def _take_slot(self) -> int:
        """The next reused output slot: two alternate, three with prefetch (one more batch is being gathered)."""
        slot = self._next_slot % (3 if self._prefetching() else 2)
        self._next_slot = slot + 1
        return slot

    def _release_event(self) -> th.cuda.Event | None:
        """A CUDA event after everything the caller queued so far: batches that expire now are no longer read."""
        if not self._transfers_to_gpu():
            return None
        event = th.cuda.Event()
        event.record(th.cuda.current_stream(_normalize_device(self.device)))
        return event

    def _take_pending(self, pending: _Pending, released: th.cuda.Event | None) -> _Gathered | None:
        """The prefetched batch; a batch restored by unpickling is gathered now, unless a step was overwritten."""
        if pending.future is not None:
            return pending.future.result()
        envs, start = pending.indices
        rows = envs * self.buffer_size + start % self.buffer_size
        if not self._has_step_rows[rows].all():
            return None
        return self._gather(pending.indices, pending.slot, released)

    def _draw(self, batch_size: int) -> np.ndarray:
        """``(2, batch_size)``: env and absolute index of the newest observation frame of uniformly drawn steps."""
        # Slots [0, filled) of each env's ring are written; draw uniformly among them and keep step slots.
        capacity = self.buffer_size
        filled = np.minimum(self._head + 1, capacity)
        ends = np.cumsum(filled)
        envs_chosen, slots_chosen = [], []
        missing = batch_size
        while missing > 0:
            flat = self._rng.integers(0, ends[-1], size=2 * missing + 8)
            envs = np.searchsorted(ends, flat, side="right")
            slots = flat - (ends[envs] - filled[envs])
            keep = np.flatnonzero(self._has_step_rows[envs * capacity + slots])[:missing]
            envs_chosen.append(envs[keep])
            slots_chosen.append(slots[keep])
            missing -= len(keep)
        envs, slots = np.concatenate(envs_chosen), np.concatenate(slots_chosen)
        head = self._head[envs]
        return np.stack([envs, head - (head - slots) % capacity])

    def _gather(self, indices: np.ndarray, slot: int, released: th.cuda.Event | None) -> _Gathered:
        """Gather the drawn transitions and windows on the storage device into the reused outputs of ``slot``."""
        storage, capacity, stack = self.storage_device, self.buffer_size, self.frame_stack
        drawn = th.from_numpy(indices)
        envs, start = (drawn.pin_memory() if storage.type == "cuda" else drawn).to(storage, non_blocking=True)
        span = max(self.n_steps, self.horizon)
        base = (envs * capacity)[:, None]
        steps = start[:, None] + th.arange(span, device=storage)  # absolute index of steps t .. t + span - 1
        step_rows = base + steps % capacity
        valid = self._step_flags[step_rows].cummin(dim=1).values  # inside the episode
        n_valid = valid[:, : self.n_steps].sum(dim=1)  # m >= 1 steps summed
        zero_row = self._frames.shape[0] - 1
        masked_rows = th.where(valid, step_rows, zero_row)
        context = th.arange(1 - stack, 1, device=storage)
        frame_rows = (
            base + (start[:, None] + context) % capacity,
            base + ((start + n_valid)[:, None] + context) % capacity,
            th.where(valid[:, : self.horizon], base + (steps[:, : self.horizon] + 1) % capacity, zero_row),
        )
        batch = len(start)
        shapes = [(batch, *self.obs_shape), (batch, *self.obs_shape), (batch, self.horizon, *self.frame_shape)]
        outputs = self._slots[slot].frame_outputs(shapes, storage, pin=self._transfers_to_gpu())
        for rows, output in zip(frame_rows, outputs, strict=True):
            th.index_select(self._frames, 0, rows.reshape(-1), out=output.view(-1, *self.frame_shape))
        gathered = _Gathered(
            observations=outputs[0],
            actions=self._actions[step_rows[:, 0]],
            next_observations=outputs[1],
            dones=self._terminals[step_rows.gather(1, (n_valid - 1)[:, None])].float(),
            future_actions=self._actions[masked_rows[:, : self.horizon]],
            future_frames=outputs[2],
            step_rewards=self._rewards[masked_rows],
            valid=valid,
        )
        if self._transfers_to_gpu():
            self._copy_frames(gathered, slot, released)
        return gathered

    def _copy_frames(self, gathered: _Gathered, slot: int, released: th.cuda.Event | None) -> None:
        """Copy the pinned frames to the training GPU on a side stream, once the batch they replace is released."""
        device = _normalize_device(self.device)
        if self._copy_stream is None:
            self._copy_stream = th.cuda.Stream(device)
        outputs = self._slots[slot]
        targets = outputs.device_outputs(device)
        with th.cuda.stream(self._copy_stream):
            if released is not None:
                self._copy_stream.wait_event(released)
            for target, source in zip(targets, outputs.frames, strict=True):
                target.copy_(source, non_blocking=True)
            outputs.copied = gathered.copied = th.cuda.Event()
            gathered.copied.record(self._copy_stream)
        gathered.observations, gathered.next_observations, gathered.future_frames = targets

    def _finish(self, gathered: _Gathered, env: VecNormalize | None) -> SequenceReplayBufferSamples:
        """Move the batch to the training device and sum the n-step rewards (normalised by ``env``'s statistics now)."""
        device = self.device
        if gathered.copied is not None:
            th.cuda.current_stream(_normalize_device(device)).wait_event(gathered.copied)
        # Host to GPU copies may run behind the caller (they are stream-ordered); GPU to host ones must not.
        non_blocking = device.type == "cuda"
        fields = [name for name in _Gathered.__annotations__ if name != "copied"]
        g = _Gathered(*(getattr(gathered, name).to(device, non_blocking=non_blocking) for name in fields))
        step_rewards = g.step_rewards
        if env is not None:
            normalized = np.asarray(env.normalize_reward(step_rewards.cpu().numpy()), dtype=np.float32)
            step_rewards = th.as_tensor(normalized, device=device) * g.valid
        n_valid = g.valid[:, : self.n_steps].sum(dim=1, keepdim=True)
        discounts = self.gamma ** th.arange(self.n_steps, dtype=th.float32, device=device)
        return SequenceReplayBufferSamples(
            observations=g.observations,
            actions=g.actions,
            next_observations=g.next_observations,
            dones=g.dones,
            rewards=(step_rewards[:, : self.n_steps] * discounts).sum(dim=1, keepdim=True),
            discounts=th.pow(self.gamma, n_valid.float()),
            future_actions=g.future_actions,
            future_frames=g.future_frames,
            future_rewards=step_rewards[:, : self.horizon].contiguous(),
            future_mask=g.valid[:, : self.horizon].contiguous(),
        )

    def _wait(self, pending: _Pending) -> None:
        """Block until ``pending``'s gather has finished (its error, if any, is dropped with it)."""
        if pending.future is not None:
            pending.future.exception()

    def _wait_for_prefetch(self) -> None:
        """Writes wait for a background gather: it reads the storage as it was when its batch was drawn."""
        if self._pending is not None:
            self._wait(self._pending)

    def _drop_pending(self) -> None:
        """Forget the prefetched batch (its outputs are reused next)."""
        if self._pending is not None:
            self._wait(self._pending)
            self._next_slot = self._pending.slot
            self._pending = None

    # ------------------------------------------------------------- save / load
    def __getstate__(self) -> dict[str, Any]:
        """Pickle the written frames themselves (memory-mapped or not, from any device) as NumPy arrays, so a saved
        buffer is self-contained and loads on any machine; a prefetched batch is kept as its drawn indices. A buffer
        with nothing written pickles no storage (``_stored`` is None) and is allocated again at its first add()."""
        self._wait_for_prefetch()
        state = self.__dict__.copy()
        for name in (
            "_frames",
            "_frame_map",
            "_actions",
            "_rewards",
            "_terminals",
            "_step_flags",
            "_slots",
            "_next_slot",
            "_pending",
            "_executor",
            "_copy_stream",
        ):
            state.pop(name, None)
        written = int(min(self._head.max() + 1, self.buffer_size))
        state["_stored"] = None
        if written > 0:
            rows = [slice(env * self.buffer_size, env * self.buffer_size + written) for env in range(self.n_envs)]
            state["_stored"] = {
                "frames": [self._frames[env_rows].cpu().numpy() for env_rows in rows],  # no copies in host storage
                "steps": {name: getattr(self, name).cpu().numpy() for name in ("_actions", "_rewards", "_terminals")},
            }
        pending = self._pending
        state["_pending_draw"] = None if pending is None else (pending.batch_size, pending.indices)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        """Rebuild the storage where it belongs on this machine (a fresh memmap file when ``memmap_dir`` is set) and
        copy the frames in; a pickle without frames leaves the allocation to the first add()."""
        if "_stored" not in state:
            raise ValueError(
                "SequenceReplayBuffer expects a pickle with torch storage (written since storage_device exists), got "
                "one from an older sb3-ef: load and sample it with the version that saved it"
            )
        stored, pending = state.pop("_stored"), state.pop("_pending_draw")
        self.__dict__.update(state)
        if self._device.type == "cuda" and not th.cuda.is_available():
            self._device = th.device("cpu")
        self.storage_device = self._resolve_storage()
        if stored is not None:
            self._allocate_storage(self.storage_device)
            for env, frames in enumerate(stored["frames"]):
                start = env * self.buffer_size
                self._frames[start : start + len(frames)] = th.from_numpy(frames)
            for name, values in stored["steps"].items():
                getattr(self, name).copy_(th.from_numpy(values))
        self._init_runtime()
        if pending is not None:
            self._pending = _Pending(pending[0], pending[1], self._take_slot())


def _normalize_device(device: th.device | str) -> th.device:
    """``cuda`` with its index filled in, so that devices compare equal to their tensors' ``.device``."""
    device = th.device(device)
    if device.type == "cuda" and device.index is None:
        return th.device("cuda", th.cuda.current_device())
    return device


def _zeros(shape: tuple[int, ...], dtype: th.dtype, device: th.device) -> th.Tensor:
    """Zeros on ``device``; in host memory through ``np.zeros`` (calloc), whose pages the OS commits when written."""
    if device.type != "cpu":
        return th.zeros(shape, dtype=dtype, device=device)
    numpy_dtype = th.empty(0, dtype=dtype).numpy().dtype
    return th.from_numpy(np.zeros(shape, dtype=numpy_dtype))


def _write_rows(target: th.Tensor, rows: list[int] | np.ndarray, values: np.ndarray) -> None:
    """``target[rows] = values`` on the target's device (through pinned memory, without blocking, on a CUDA GPU)."""
    source, index = th.from_numpy(np.ascontiguousarray(values)), th.as_tensor(np.asarray(rows, dtype=np.int64))
    if target.device.type != "cpu":
        cuda = target.device.type == "cuda"
        source = (source.pin_memory() if cuda else source).to(target.device, non_blocking=cuda)
        index = (index.pin_memory() if cuda else index).to(target.device, non_blocking=cuda)
    target.index_copy_(0, index, source)
