"""SB3's ReplayBuffer arrays (observations, next_observations, actions, rewards, dones, timeouts, pos, full) of a
SequenceReplayBuffer, against SB3's own ReplayBuffer filled with the same multi-env stream."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from test_buffers import ACTION_DIM, FRAME, STORAGES, Streams, make_buffer

NAMES = ("observations", "next_observations", "actions", "rewards", "dones", "timeouts")


def filled_pair(capacity: int, adds: int, storage: str = "cpu", handle_timeout: bool = True, seed: int = 0):
    """Both buffers, 2 envs, stack 3, after ``adds`` steps of episodes that terminate, time out or are cut."""
    n_envs, frame_stack = 2, 3
    ours = make_buffer(n_envs, frame_stack, capacity, storage, handle_timeout_termination=handle_timeout)
    obs_space = spaces.Box(0, 255, (3 * frame_stack, *FRAME[1:]), np.uint8)
    sb3 = ReplayBuffer(
        capacity * n_envs,
        obs_space,
        spaces.Box(-1, 1, (ACTION_DIM,), np.float32),
        device="cpu",
        n_envs=n_envs,
        handle_timeout_termination=handle_timeout,
    )
    streams = Streams(n_envs, frame_stack, 6, "distinct", handle_timeout, seed)
    for _ in range(adds):
        streams.step(ours, sb3)
    return ours, sb3


@pytest.mark.parametrize("storage", STORAGES)
@pytest.mark.parametrize("handle_timeout", [True, False])
def test_arrays_equal_sb3_replay_buffer_before_the_rings_wrap(storage, handle_timeout):
    ours, sb3 = filled_pair(capacity=100, adds=25, storage=storage, handle_timeout=handle_timeout)
    assert (ours.pos, ours.full) == (sb3.pos, sb3.full) == (25, False)
    assert ours.timeouts.any() == handle_timeout  # the stream has time limits
    for name in NAMES:
        got, expected = np.asarray(getattr(ours, name)), getattr(sb3, name)
        assert (got.shape, got.dtype) == (expected.shape, expected.dtype), name
        np.testing.assert_array_equal(got, expected, err_msg=name)


def test_after_wrapping_the_stored_steps_sit_in_sb3_rows_and_the_rest_read_zero():
    """Rings of 30 frames hold fewer than 30 transitions: SB3 keeps the last 30 add() calls, the sequence buffer the
    last size() of them, in the same rows; the older rows read as zeros."""
    ours, sb3 = filled_pair(capacity=30, adds=80)
    assert (ours.pos, ours.full) == (sb3.pos, sb3.full) == (80 % 30, True)
    observations = np.asarray(ours.observations)
    held = observations[:, :, 0, 0, 0] != 0  # env index + 1 is encoded in every stored frame
    assert held.sum() == ours.size() < sb3.size() * 2
    for env in range(2):
        newest_first = (ours.pos - 1 - np.arange(30)) % 30
        column = held[newest_first, env]
        assert column[: column.sum()].all() and not column[column.sum() :].any()  # the latest add() calls
    for name in NAMES:
        got, expected = np.asarray(getattr(ours, name)), getattr(sb3, name)
        np.testing.assert_array_equal(got[held], expected[held], err_msg=name)
        assert not got[~held].any(), name


def test_observation_view_indexes_like_an_array():
    ours, sb3 = filled_pair(capacity=100, adds=25)
    view = ours.observations
    assert view.shape == sb3.observations.shape and len(view) == 100 and view.ndim == 5 and view.dtype == np.uint8
    last = ours.pos - 1
    for key in (
        last,
        (last, 1),
        slice(3, 9),
        (slice(None), 0),
        np.array([0, 5, last]),
        (slice(0, 4), 1, slice(-3, None)),
    ):
        np.testing.assert_array_equal(view[key], sb3.observations[key], err_msg=str(key))
    np.testing.assert_array_equal(view[..., -3:, 0, 0], sb3.observations[..., -3:, 0, 0])
    np.testing.assert_array_equal(ours.next_observations[: ours.pos], sb3.next_observations[: sb3.pos])


def test_arrays_are_read_only_copies_and_empty_before_the_first_add():
    empty = make_buffer(2, 3, 30)
    assert empty.actions.shape == (30, 2, ACTION_DIM) and not empty.actions.any()
    assert not np.asarray(empty.observations).any()
    ours, _ = filled_pair(capacity=100, adds=5)
    with pytest.raises(ValueError, match="read-only"):
        ours.rewards[0] = 1.0
