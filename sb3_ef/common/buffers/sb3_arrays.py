"""SB3's ``(buffer_size, n_envs, ...)`` ``ReplayBuffer`` arrays derived from a sequence buffer (docs/buffer.md)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_ef.common.buffers.episodes import EpisodeRings
from sb3_ef.common.buffers.storage import FrameStorage


def sb3_rows(rings: EpisodeRings, pos: int) -> np.ndarray:
    """``(capacity, n_envs)`` storage row of each SB3 row (the zero row where no step is stored)."""
    capacity, zero_row = rings.capacity, rings.n_envs * rings.capacity
    rows = np.full((capacity, rings.n_envs), zero_row, dtype=np.int64)
    for env in range(rings.n_envs):
        steps = rings.steps_in_order(env)[::-1]
        rows[(pos - 1 - np.arange(len(steps))) % capacity, env] = steps
    return rows


class StackedFrameView:
    """Read-only ``(buffer_size, n_envs, 3k, h, w)`` array of the (next, ``offset=1``) observations of ``rows``."""

    dtype = np.dtype(np.uint8)

    def __init__(self, storage: FrameStorage, rows: np.ndarray, capacity: int, frame_stack: int, offset: int) -> None:
        self._storage, self._rows, self._capacity = storage, rows, capacity
        self._frame_stack, self._offset = frame_stack, offset
        channels, height, width = storage.frame_shape
        self.shape = (*rows.shape, frame_stack * channels, height, width)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    def __len__(self) -> int:
        return self.shape[0]

    def __repr__(self) -> str:
        return f"StackedFrameView(shape={self.shape}, dtype=uint8)"

    def __getitem__(self, key: Any) -> np.ndarray:
        key = key if isinstance(key, tuple) else (key,)
        if any(part is Ellipsis or part is None for part in key):
            return np.asarray(self)[key]
        rows = self._rows[key[:2]]
        return self._gather(np.asarray(rows))[(slice(None),) * np.ndim(rows) + key[2:]]

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        array = self._gather(self._rows)
        return array if dtype is None else array.astype(dtype)

    def _gather(self, rows: np.ndarray) -> np.ndarray:
        """The stacked frames of the steps in storage ``rows`` (any shape), as ``(*rows.shape, 3k, h, w)``."""
        storage, stack, capacity = self._storage, self._frame_stack, self._capacity
        channels, height, width = storage.frame_shape
        if not storage.allocated:
            return np.zeros((*rows.shape, stack * channels, height, width), dtype=np.uint8)
        zero_row = storage.frames.shape[0] - 1
        base, slot = rows // capacity * capacity, rows % capacity
        context = np.arange(1 - stack, 1) + self._offset
        frame_rows = base[..., None] + (slot[..., None] + context) % capacity
        frame_rows[rows == zero_row] = zero_row
        index = th.from_numpy(frame_rows.reshape(-1)).to(storage.device)
        frames = th.index_select(storage.frames, 0, index).cpu().numpy()
        return frames.reshape(*rows.shape, stack * channels, height, width)


def step_array_property(name: str) -> Any:
    """A buffer property: a read-only copy of SB3's float32 array ``name``."""

    def array(buffer: Any) -> np.ndarray:
        storage, rows = buffer._storage, buffer._sb3_rows()
        if storage.allocated:
            values = getattr(storage, name)[th.from_numpy(rows).to(storage.device)].cpu().numpy().astype(np.float32)
        else:
            values = np.zeros((*rows.shape, storage.action_dim) if name == "actions" else rows.shape, np.float32)
        values.flags.writeable = False
        return values

    return property(array, doc=f"SB3's ``(buffer_size, n_envs, ...)`` float32 {name} (a read-only copy).")
