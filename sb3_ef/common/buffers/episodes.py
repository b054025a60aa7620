"""Writing into per-env frame rings: the checks before storing and the episode bookkeeping (docs/buffer.md)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

#: The info key of an env step that holds the agent masks of the step's frames (``make_env(..., agent_masks=True)``).
MASKS_INFO_KEY = "agent_masks"


@dataclass
class Placement:
    """Where one ``add()`` writes: new frames, step rows, rows whose step flag changed, envs that started an episode."""

    frame_rows: list[int]
    frames: list[np.ndarray]
    step_rows: np.ndarray
    touched_rows: np.ndarray
    started: np.ndarray


class EpisodeRings:
    """The host-side bookkeeping of ``n_envs`` rings of ``capacity`` frame slots."""

    def __init__(
        self, n_envs: int, capacity: int, frame_stack: int, frame_channels: int, obs_shape: tuple[int, ...]
    ) -> None:
        self.n_envs, self.capacity = n_envs, capacity
        self.frame_stack, self.frame_channels = frame_stack, frame_channels
        # has_step_rows[e * capacity + s]: slot s of env e carries a step; the last row, always False, pads reads.
        self.has_step_rows = np.zeros(n_envs * capacity + 1, dtype=bool)
        self.head = np.full(n_envs, -1, dtype=np.int64)  # absolute index of the newest frame per env
        self.episode_open = np.zeros(n_envs, dtype=bool)  # the env's last step did not end its episode
        self.last_obs = np.zeros((n_envs, *obs_shape), dtype=np.uint8)  # the stack whose newest frame is head
        self.n_transitions = 0  # steps that can be sampled
        self.n_adds = 0  # add() calls stored since construction
        self.version = 0  # changes with every write and reset (for caches of derived arrays)

    @property
    def has_step(self) -> np.ndarray:
        """``(n_envs, capacity)`` view of the step flags."""
        return self.has_step_rows[:-1].reshape(self.n_envs, self.capacity)

    def filled(self) -> np.ndarray:
        """Slots ``[0, filled)`` written so far per env."""
        return np.minimum(self.head + 1, self.capacity)

    def reset(self) -> None:
        self.has_step_rows[:] = False
        self.head[:] = -1
        self.episode_open[:] = False
        self.n_transitions = 0
        self.version += 1

    def check_step(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray) -> None:
        """Refuse non-finite values and stacks that do not slide, before anything is written."""
        checked = {"rewards": reward, "actions": action}
        if np.issubdtype(obs.dtype, np.floating):  # uint8 frames are finite by construction
            checked.update(obs=obs, next_obs=next_obs)
        for name, values in checked.items():
            finite = np.isfinite(values.reshape(self.n_envs, -1))
            if not finite.all():
                env = int(np.argmin(finite.all(axis=1)))
                value = values[env] if name not in ("obs", "next_obs") else values[env].reshape(-1)[~finite[env]][0]
                raise ValueError(
                    f"SequenceReplayBuffer.add expects finite {name}, got {value} for env {env} at step "
                    f"{self.n_adds} (add() calls so far); nothing of this call was stored"
                )
        channels = self.frame_channels
        for env in range(self.n_envs):
            if not np.array_equal(next_obs[env, :-channels], obs[env, channels:]):
                raise ValueError(
                    "SequenceReplayBuffer expects frame stacks that slide by one frame per step "
                    f"(next_obs[{env}][:-{channels}] == obs[{env}][{channels}:]), got stacks that differ"
                )

    def step_masks(self, infos: list[dict[str, Any]], frame_size: tuple[int, int]) -> np.ndarray:
        """The ``(n_envs, k + 1, h, w)`` 0/1 masks of each step's frames (those of ``obs`` then the new one)."""
        expected = (self.frame_stack + 1, *frame_size)
        masks = []
        for env, info in enumerate(infos):
            if MASKS_INFO_KEY not in info:
                raise ValueError(
                    f"SequenceReplayBuffer(store_masks=True) expects infos[{env}][{MASKS_INFO_KEY!r}] (the agent masks "
                    f"of the step's frames), got an info with keys {sorted(info)}: build the env with "
                    "sb3_ef.envs.make_env(..., agent_masks=True)"
                )
            mask = np.asarray(info[MASKS_INFO_KEY])
            if mask.shape != expected:
                raise ValueError(
                    f"SequenceReplayBuffer expects infos[{env}][{MASKS_INFO_KEY!r}] of shape {expected} (one mask per "
                    f"frame of obs and of the new frame, oldest first), got shape {mask.shape}"
                )
            masks.append(mask != 0)
        return np.stack(masks)

    def place(self, obs: np.ndarray, next_obs: np.ndarray, done: np.ndarray) -> Placement:
        """Book one checked step of every env; an ``obs`` that does not continue the episode starts a new one."""
        frame_rows: list[int] = []
        frames: list[np.ndarray] = []
        cleared: list[np.ndarray] = []
        step_rows = np.empty(self.n_envs, dtype=np.int64)
        started = np.zeros(self.n_envs, dtype=bool)
        frame_shape = (self.frame_channels, *obs.shape[2:])
        for env in range(self.n_envs):
            if not (self.episode_open[env] and np.array_equal(obs[env], self.last_obs[env])):
                started[env] = True
                for frame in obs[env].reshape(self.frame_stack, *frame_shape):
                    frame_rows.append(self._advance(env, cleared))
                    frames.append(frame)
            step_rows[env] = env * self.capacity + self.head[env] % self.capacity
            self.has_step_rows[step_rows[env]] = True
            self.n_transitions += 1
            frame_rows.append(self._advance(env, cleared))
            frames.append(next_obs[env, -self.frame_channels :])
            self.last_obs[env] = next_obs[env]
            self.episode_open[env] = not done[env]
        self.n_adds += 1
        self.version += 1
        touched = np.unique(np.concatenate([step_rows, *cleared]))
        return Placement(frame_rows, frames, step_rows, touched, started)

    def _advance(self, env: int, cleared: list[np.ndarray]) -> int:
        """The row of ``env``'s next slot; the steps that read an overwritten frame are cleared (into ``cleared``)."""
        newest = self.head[env] + 1
        slot = newest % self.capacity
        if newest >= self.capacity:
            # The steps whose observation holds the overwritten frame: this slot and the next k - 1.
            readers = env * self.capacity + np.arange(slot, slot + self.frame_stack) % self.capacity
            self.n_transitions -= int(self.has_step_rows[readers].sum())
            self.has_step_rows[readers] = False
            cleared.append(readers)
        self.head[env] = newest
        return env * self.capacity + slot

    def steps_in_order(self, env: int) -> np.ndarray:
        """Rows of ``env``'s stored steps (its latest ones), oldest first."""
        filled = int(self.filled()[env])
        oldest = self.head[env] + 1 if filled == self.capacity else 0
        slots = (oldest + np.arange(filled)) % self.capacity
        rows = env * self.capacity + slots
        return rows[self.has_step_rows[rows]]
