"""Sampling a sequence buffer: host draws, gathers on the storage device, prefetch, pinned copies (docs/buffer.md)."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from sb3_ef.common.buffers.episodes import EpisodeRings
from sb3_ef.common.buffers.storage import FrameStorage, normalize_device

_SEED_SALT = 0x5EB3EF  # keeps the buffer's stream apart from torch's own stream of the same seed


class SequenceReplayBufferSamples(NamedTuple):
    """One batch: n-step RL transitions plus the windows that start at the same steps (docs/buffer.md)."""

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
    masks: th.Tensor | None = None


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
    packed_masks: th.Tensor | None = None  # (B, k, mask bytes) bit-packed masks of the observation's frames
    copied: Any = None  # CUDA event: the batch has reached the training device


_MOVED = ("observations", "actions", "next_observations", "dones", "future_actions", "future_frames")


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


class BatchSampler:
    """Draws and gathers n-step transitions with their windows from ``storage``, where ``rings`` say steps are."""

    def __init__(
        self,
        storage: FrameStorage,
        rings: EpisodeRings,
        n_steps: int,
        gamma: float,
        horizon: int,
        mask_size: tuple[int, int] | None,
        prefetch: bool | None,
        seed: int,
    ) -> None:
        self.storage, self.rings = storage, rings
        self.n_steps, self.gamma, self.horizon = n_steps, gamma, horizon
        self.mask_size, self.prefetch = mask_size, prefetch
        self.obs_shape = (rings.frame_stack * storage.frame_shape[0], *storage.frame_shape[1:])
        self._slots = [_OutputSlot() for _ in range(3)]
        self._next_slot = 0
        self._pending: _Pending | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._copy_stream: th.cuda.Stream | None = None
        self.seed(seed)

    def seed(self, seed: int) -> None:
        """Restart the stream from ``seed`` (a prefetched batch is dropped)."""
        self.drop_pending()
        self.rng = np.random.default_rng((seed, _SEED_SALT))

    def sample(self, batch_size: int, device: th.device, env: VecNormalize | None) -> SequenceReplayBufferSamples:
        """A batch on ``device`` (see :meth:`SequenceReplayBuffer.sample`)."""
        released = self._release_event(device)
        pending, self._pending = self._pending, None
        gathered = None
        if pending is not None:
            gathered = self._take_pending(pending, device, released) if pending.batch_size == batch_size else None
            if gathered is None:
                self._wait(pending)
                self._next_slot = pending.slot  # reuse its outputs, so that no handed-out batch is overwritten
        if gathered is None:
            gathered = self._gather(self._draw(batch_size), self._take_slot(device), device, released)
        if self._prefetching(device):
            indices, slot = self._draw(batch_size), self._take_slot(device)
            if self._executor is None:
                self._executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="sb3_ef_prefetch")
            future = self._executor.submit(self._gather, indices, slot, device, released)
            self._pending = _Pending(batch_size, indices, slot, future)
        return self._finish(gathered, device, env)

    def _transfers_to_gpu(self, device: th.device) -> bool:
        return self.storage.device.type == "cpu" and device.type == "cuda"

    def _prefetching(self, device: th.device) -> bool:
        return self.prefetch if self.prefetch is not None else self._transfers_to_gpu(device)

    def _take_slot(self, device: th.device) -> int:
        """The next reused output slot: two alternate, three with prefetch (one more batch is being gathered)."""
        slot = self._next_slot % (3 if self._prefetching(device) else 2)
        self._next_slot = slot + 1
        return slot

    def _release_event(self, device: th.device) -> th.cuda.Event | None:
        """A CUDA event after everything the caller queued so far: batches that expire now are no longer read."""
        if not self._transfers_to_gpu(device):
            return None
        event = th.cuda.Event()
        event.record(th.cuda.current_stream(normalize_device(device)))
        return event

    def _take_pending(self, pending: _Pending, device: th.device, released: th.cuda.Event | None) -> _Gathered | None:
        """The prefetched batch; a batch restored by unpickling is gathered now, unless a step was overwritten."""
        if pending.future is not None:
            return pending.future.result()
        envs, start = pending.indices
        rows = envs * self.rings.capacity + start % self.rings.capacity
        if not self.rings.has_step_rows[rows].all():
            return None
        return self._gather(pending.indices, pending.slot, device, released)

    def _draw(self, batch_size: int) -> np.ndarray:
        """``(2, batch_size)``: env and absolute index of the newest observation frame of uniformly drawn steps."""
        capacity, has_step_rows = self.rings.capacity, self.rings.has_step_rows
        filled = self.rings.filled()
        ends = np.cumsum(filled)
        envs_chosen, slots_chosen = [], []
        missing = batch_size
        while missing > 0:
            flat = self.rng.integers(0, ends[-1], size=2 * missing + 8)
            envs = np.searchsorted(ends, flat, side="right")
            slots = flat - (ends[envs] - filled[envs])
            keep = np.flatnonzero(has_step_rows[envs * capacity + slots])[:missing]
            envs_chosen.append(envs[keep])
            slots_chosen.append(slots[keep])
            missing -= len(keep)
        envs, slots = np.concatenate(envs_chosen), np.concatenate(slots_chosen)
        head = self.rings.head[envs]
        return np.stack([envs, head - (head - slots) % capacity])

    def _gather(self, indices: np.ndarray, slot: int, device: th.device, released: th.cuda.Event | None) -> _Gathered:
        """Gather the drawn transitions and windows on the storage device into the reused outputs of ``slot``."""
        store, capacity, stack = self.storage, self.rings.capacity, self.rings.frame_stack
        storage, frame_shape = store.device, store.frame_shape
        drawn = th.from_numpy(indices)
        envs, start = (drawn.pin_memory() if storage.type == "cuda" else drawn).to(storage, non_blocking=True)
        span = max(self.n_steps, self.horizon)
        base = (envs * capacity)[:, None]
        steps = start[:, None] + th.arange(span, device=storage)  # absolute index of steps t .. t + span - 1
        step_rows = base + steps % capacity
        valid = store.step_flags[step_rows].cummin(dim=1).values  # inside the episode
        n_valid = valid[:, : self.n_steps].sum(dim=1)  # m >= 1 steps summed
        zero_row = store.frames.shape[0] - 1
        masked_rows = th.where(valid, step_rows, zero_row)
        context = th.arange(1 - stack, 1, device=storage)
        frame_rows = (
            base + (start[:, None] + context) % capacity,
            base + ((start + n_valid)[:, None] + context) % capacity,
            th.where(valid[:, : self.horizon], base + (steps[:, : self.horizon] + 1) % capacity, zero_row),
        )
        batch = len(start)
        shapes = [(batch, *self.obs_shape), (batch, *self.obs_shape), (batch, self.horizon, *frame_shape)]
        pin = self._transfers_to_gpu(device)
        outputs = self._slots[slot].frame_outputs(shapes, storage, pin=pin)
        for rows, output in zip(frame_rows, outputs, strict=True):
            th.index_select(store.frames, 0, rows.reshape(-1), out=output.view(-1, *frame_shape))
        last_rows = step_rows.gather(1, (n_valid - 1)[:, None])
        gathered = _Gathered(
            observations=outputs[0],
            actions=store.actions[step_rows[:, 0]],
            next_observations=outputs[1],
            dones=(store.dones[last_rows] & ~store.timeouts[last_rows]).float(),
            future_actions=store.actions[masked_rows[:, : self.horizon]],
            future_frames=outputs[2],
            step_rewards=store.rewards[masked_rows],
            valid=valid,
            packed_masks=None if store.masks is None else store.masks[frame_rows[0]],
        )
        if pin:
            self._copy_frames(gathered, slot, device, released)
        return gathered

    def _copy_frames(self, gathered: _Gathered, slot: int, device: th.device, released: th.cuda.Event | None) -> None:
        """Copy the pinned frames to the training GPU on a side stream, once the batch they replace is released."""
        device = normalize_device(device)
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

    def _finish(self, gathered: _Gathered, device: th.device, env: VecNormalize | None) -> SequenceReplayBufferSamples:
        """The batch on the training device with its n-step rewards (normalised by ``env``'s statistics now)."""
        if gathered.copied is not None:
            th.cuda.current_stream(normalize_device(device)).wait_event(gathered.copied)
        # Host to GPU copies may run behind the caller (they are stream-ordered); GPU to host ones must not.
        non_blocking = device.type == "cuda"
        g = {name: getattr(gathered, name).to(device, non_blocking=non_blocking) for name in _MOVED}
        step_rewards = gathered.step_rewards.to(device, non_blocking=non_blocking)
        valid = gathered.valid.to(device, non_blocking=non_blocking)
        if env is not None:
            normalized = np.asarray(env.normalize_reward(step_rewards.cpu().numpy()), dtype=np.float32)
            step_rewards = th.as_tensor(normalized, device=device) * valid
        n_valid = valid[:, : self.n_steps].sum(dim=1, keepdim=True)
        discounts = self.gamma ** th.arange(self.n_steps, dtype=th.float32, device=device)
        return SequenceReplayBufferSamples(
            **g,
            rewards=(step_rewards[:, : self.n_steps] * discounts).sum(dim=1, keepdim=True),
            discounts=th.pow(self.gamma, n_valid.float()),
            future_rewards=step_rewards[:, : self.horizon].contiguous(),
            future_mask=valid[:, : self.horizon].contiguous(),
            masks=self._unpack_masks(gathered.packed_masks, device, non_blocking),
        )

    def _unpack_masks(self, packed: th.Tensor | None, device: th.device, non_blocking: bool) -> th.Tensor | None:
        """``(B, k, mask bytes)`` bit-packed masks (NumPy's big-endian ``packbits``) as uint8 ``(B, k, h, w)``."""
        if packed is None:
            return None
        packed = packed.to(device, non_blocking=non_blocking)
        shifts = th.arange(7, -1, -1, dtype=th.uint8, device=device)
        bits = (packed.unsqueeze(-1) >> shifts) & 1
        assert self.mask_size is not None, "masks are gathered only where they are stored"
        height, width = self.mask_size
        return bits.flatten(-2)[..., : height * width].unflatten(-1, (height, width))

    def _wait(self, pending: _Pending) -> None:
        """Block until ``pending``'s gather has finished (its error, if any, is dropped with it)."""
        if pending.future is not None:
            pending.future.exception()

    def wait_for_prefetch(self) -> None:
        """Writes wait for a background gather, which reads the storage as it was when drawn."""
        if self._pending is not None:
            self._wait(self._pending)

    def drop_pending(self) -> None:
        """Forget the prefetched batch (its outputs are reused next)."""
        if self._pending is not None:
            self._wait(self._pending)
            self._next_slot = self._pending.slot
            self._pending = None

    def pending_draw(self) -> tuple[int, np.ndarray] | None:
        """What a pickle keeps of the prefetched batch: its size and drawn indices."""
        self.wait_for_prefetch()
        return None if self._pending is None else (self._pending.batch_size, self._pending.indices)

    def restore_pending(self, draw: tuple[int, np.ndarray] | None, device: th.device) -> None:
        """A pickled prefetched batch, gathered at the next ``sample()`` of its size."""
        if draw is not None:
            self._pending = _Pending(draw[0], draw[1], self._take_slot(device))
