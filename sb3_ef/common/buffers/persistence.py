"""Pickling a sequence buffer as one flat dict of NumPy fields, loadable on any machine (docs/buffer.md).
A pickle with ``_terminals`` (no ``_dones``/``_timeouts``) loads with dones = terminations, no timeouts, no masks."""

from __future__ import annotations

from typing import Any, Protocol

import torch as th

from sb3_ef.common.buffers.episodes import EpisodeRings
from sb3_ef.common.buffers.sampling import BatchSampler
from sb3_ef.common.buffers.storage import FrameStorage


class PersistedBuffer(Protocol):
    """What pickling reads and rebuilds of a :class:`~sb3_ef.common.buffers.SequenceReplayBuffer`."""

    _rings: EpisodeRings
    _storage: FrameStorage
    _sampler: BatchSampler
    _device: th.device
    storage_request: str | th.device
    storage_device: th.device

    @property
    def device(self) -> th.device: ...

    def _build_parts(self, prefetch: bool | None, seed: int = 0) -> None: ...


#: Attributes rebuilt at load rather than pickled.
_PARTS = ("_rings", "_storage", "_sampler", "_sb3_rows_cache")
#: The bookkeeping fields of EpisodeRings, pickled under these names.
_RING_FIELDS = {
    f"_{name}": name for name in ("has_step_rows", "head", "episode_open", "last_obs", "n_transitions", "n_adds")
}
_STEP_FIELDS = {f"_{name}": name for name in FrameStorage.STEP_TENSORS}


def buffer_state(buffer: PersistedBuffer) -> dict[str, Any]:
    """The pickled state: attributes, bookkeeping, sampler state and the written storage (``_stored``, or None)."""
    state = {name: value for name, value in buffer.__dict__.items() if name not in _PARTS}
    rings, storage, sampler = buffer._rings, buffer._storage, buffer._sampler
    state["_pending_draw"] = sampler.pending_draw()
    state["_rng"] = sampler.rng
    state["prefetch"] = sampler.prefetch
    for field, attribute in _RING_FIELDS.items():
        state[field] = getattr(rings, attribute)
    written = int(min(rings.head.max() + 1, rings.capacity))
    state["_stored"] = None
    if written > 0:
        rows = [slice(env * rings.capacity, env * rings.capacity + written) for env in range(rings.n_envs)]
        state["_stored"] = {
            "frames": [storage.frames[env_rows].cpu().numpy() for env_rows in rows],  # no copies in host storage
            "steps": {field: getattr(storage, name).cpu().numpy() for field, name in _STEP_FIELDS.items()},
            "masks": None if storage.masks is None else storage.masks.cpu().numpy(),
        }
    return state


def restore_buffer(buffer: PersistedBuffer, state: dict[str, Any]) -> None:
    """Rebuild the buffer's parts on this machine from :func:`buffer_state`'s dict, then copy the data in."""
    if "_stored" not in state:
        raise ValueError(
            "SequenceReplayBuffer expects a pickle whose frames are stored under '_stored', got one without: "
            "this package cannot read that format; load and use it with the sb3-ef version that saved it"
        )
    state = dict(state)
    stored, pending, rng = state.pop("_stored"), state.pop("_pending_draw"), state.pop("_rng")
    prefetch = state.pop("prefetch")
    rings_state = {attribute: state.pop(field) for field, attribute in _RING_FIELDS.items()}
    if "store_masks" not in state:  # saved without masks, timeouts or SB3's position
        state["store_masks"] = False
        state["pos"] = rings_state["n_adds"] % state["buffer_size"]
        state["full"] = rings_state["n_adds"] >= state["buffer_size"]
    buffer.__dict__.update(state)
    if buffer._device.type == "cuda" and not th.cuda.is_available():
        buffer._device = th.device("cpu")
    buffer._build_parts(prefetch)
    rings, storage, sampler = buffer._rings, buffer._storage, buffer._sampler
    for attribute, value in rings_state.items():
        setattr(rings, attribute, value)
    buffer.storage_device = storage.choose_device(buffer.storage_request, buffer.device)
    if stored is not None:
        storage.allocate(buffer.storage_device, rings.has_step_rows)
        for env, frames in enumerate(stored["frames"]):
            start = env * rings.capacity
            storage.frames[start : start + len(frames)] = th.from_numpy(frames)
        steps = stored["steps"]
        if "_terminals" in steps:
            steps = {"_actions": steps["_actions"], "_rewards": steps["_rewards"], "_dones": steps["_terminals"]}
        for field, values in steps.items():
            getattr(storage, _STEP_FIELDS[field]).copy_(th.from_numpy(values))
        if stored.get("masks") is not None and storage.masks is not None:
            storage.masks.copy_(th.from_numpy(stored["masks"]))
    sampler.rng = rng
    sampler.restore_pending(pending, buffer.device)
