"""A run's evaluation CSV and result.json are replaced whole: a kill while they are written loses no row."""

from __future__ import annotations

import pytest

from sb3_ef.analysis.records import append_records, read_records, record_row, truncate_records


def rows(steps):
    return [record_row("drqv2", "dmc/cartpole-balance-v0", 0, step, 2, 100.0 + step / 7, None) for step in steps]


def test_truncation_keeps_the_earlier_rows_exactly(tmp_path):
    path = tmp_path / "run.csv"
    append_records(path, rows([100, 200, 300]))
    before = path.read_text()
    truncate_records(path, 300)
    assert path.read_text() == before  # nothing to drop: the file is left as it was
    truncate_records(path, 200)
    assert [row["step"] for row in read_records(path)] == [100, 200]
    assert path.read_text() == before.rsplit("\n", 2)[0] + "\n"  # the same text, less the last row
    truncate_records(path, 50)
    assert not path.exists()


def test_a_write_cut_short_leaves_every_row(tmp_path, monkeypatch):
    path = tmp_path / "run.csv"
    append_records(path, rows([100, 200, 300]))
    before = path.read_text()

    def full_disk(_path):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("sb3_ef.common.files._fsync", full_disk)
    with pytest.raises(OSError, match="No space left"):
        truncate_records(path, 200)
    assert path.read_text() == before and sorted(p.name for p in tmp_path.iterdir()) == ["run.csv"]
