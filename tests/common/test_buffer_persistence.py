"""Replay buffers users saved keep loading: a pickle written by sb3-ef 0.1.0's buffer (tests/common/data, made by
make_sequence_buffer_pickle.py there) loads, hands out the batches that buffer handed out, and keeps adding."""

from __future__ import annotations

import pickle
from pathlib import Path

import numpy as np
from test_buffers import Streams, check_against_reference

from sb3_ef.common.buffers import SequenceReplayBuffer

DATA = Path(__file__).parent / "data"
ADDS_BEFORE, ADDS_AFTER, BATCH = 40, 25, 16  # as make_sequence_buffer_pickle.py wrote them


def assert_batch(batch, expected: np.lib.npyio.NpzFile, name: str) -> None:
    for field, value in batch._asdict().items():
        if field == "masks":
            assert value is None  # that buffer stored no masks
            continue
        np.testing.assert_array_equal(value.numpy(), expected[f"{name}/{field}"], err_msg=f"{name}/{field}")


def test_a_buffer_pickled_by_sb3_ef_0_1_0_loads_and_continues():
    buffer = pickle.loads((DATA / "sequence_buffer_0.1.0.pkl").read_bytes())
    expected = np.load(DATA / "sequence_buffer_0.1.0_samples.npz")
    assert isinstance(buffer, SequenceReplayBuffer) and not buffer.store_masks
    assert_batch(buffer.sample(BATCH), expected, "first")  # the prefetched batch it pickled
    assert_batch(buffer.sample(BATCH), expected, "second")  # then its generator's next draw
    # SB3's position is counted from its add() calls: 40 steps in rings of 20 frames.
    assert (buffer.pos, buffer.full) == (ADDS_BEFORE % buffer.buffer_size, True)
    streams = Streams(2, 3, 6, "distinct", True, seed=3)  # the stream it was filled with, replayed
    for _ in range(ADDS_BEFORE):
        streams.step()
    for _ in range(ADDS_AFTER):
        streams.step(buffer)
    assert buffer.size() == int(expected["size"])
    assert_batch(buffer.sample(BATCH), expected, "after")
    check_against_reference(buffer, streams)


def test_a_loaded_0_1_0_buffer_pickles_again_in_the_current_format():
    buffer = pickle.loads((DATA / "sequence_buffer_0.1.0.pkl").read_bytes())
    again = pickle.loads(pickle.dumps(buffer))
    for _ in range(2):
        got, expected = again.sample(BATCH), buffer.sample(BATCH)
        for field, value in expected._asdict().items():
            assert (getattr(got, field) is None) if value is None else np.array_equal(getattr(got, field), value)
    np.testing.assert_array_equal(again.actions, buffer.actions)
    assert (again.pos, again.full) == (buffer.pos, buffer.full)
