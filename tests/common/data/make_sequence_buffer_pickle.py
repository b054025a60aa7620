"""Writes sequence_buffer_0.1.0.pkl and its expected samples with the buffer of the sb3-ef it runs under.

The committed files were written by sb3-ef 0.1.0 (the buffer as one class) so that
tests/common/test_buffer_persistence.py checks that replay buffers users saved with it still load:

    cd <an sb3-ef 0.1.0 checkout> && python <this file> <output folder>
"""

from __future__ import annotations

import pickle
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/common, for the encoded streams

from test_buffers import GAMMA, Streams, make_buffer

ADDS_BEFORE, ADDS_AFTER, BATCH = 40, 25, 16


def main(folder: Path) -> None:
    buffer = make_buffer(2, 3, 20, n_steps=2, gamma=GAMMA, horizon=3, prefetch=True)
    streams = Streams(2, 3, 6, "distinct", True, seed=3)
    for _ in range(ADDS_BEFORE):  # 40 steps in rings of 20 frames: both rings have wrapped
        streams.step(buffer)
    buffer.sample(BATCH)  # leaves a prefetched batch, which the pickle keeps as its drawn indices
    (folder / "sequence_buffer_0.1.0.pkl").write_bytes(pickle.dumps(buffer, protocol=pickle.HIGHEST_PROTOCOL))
    expected = {}
    for name in ("first", "second", "after"):
        if name == "after":
            for _ in range(ADDS_AFTER):
                streams.step(buffer)
        batch = buffer.sample(BATCH)  # copied: the buffer reuses its output tensors
        expected.update({f"{name}/{field}": getattr(batch, field).numpy().copy() for field in batch._fields})
    expected["size"] = np.array(buffer.size())
    np.savez_compressed(folder / "sequence_buffer_0.1.0_samples.npz", **expected)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
