"""1-d actions (cartpole's) in LeRobot datasets: LeRobot stores a feature of shape [1] as a scalar column of its
dtype (``datasets.Value``; longer vectors as fixed-size lists), and its reader refuses a list of one there. The
writer follows it; the reader takes both forms."""

from __future__ import annotations

import json

import numpy as np
import pytest

from sb3_ef.offline.episodes import Episode, make_episode
from tests.helpers.offline import square_episode

pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
pytest.importorskip("av")

from sb3_ef.offline.lerobot import write_lerobot  # noqa: E402
from sb3_ef.offline.readers import open_dataset  # noqa: E402

DATA = "data/chunk-000/file-000.parquet"


def one_d_episodes() -> list[Episode]:
    episodes = [square_episode(steps=8 + seed, seed=seed) for seed in range(2)]
    return [make_episode(ep.frames, ep.actions[:, :1], ep.masks, source=ep.source) for ep in episodes]


def test_a_1d_action_is_a_float_column_as_lerobot_stores_shape_1(tmp_path):
    data = one_d_episodes()
    write_lerobot(tmp_path, data, codec="libx264rgb")
    assert pq.read_schema(tmp_path / DATA).field("action").type == pa.float32()
    features = json.loads((tmp_path / "meta/info.json").read_text())["features"]
    assert features["action"] == {"dtype": "float32", "shape": [1], "names": None}
    for original, read in zip(data, open_dataset(tmp_path), strict=True):
        assert read.actions.shape == (original.steps, 1)
        np.testing.assert_array_equal(read.actions, original.actions)


def test_a_list_of_one_is_read_as_well(tmp_path):
    data = one_d_episodes()
    write_lerobot(tmp_path, data, codec="libx264rgb")
    table = pq.read_table(tmp_path / DATA)
    column = table.column("action").combine_chunks()
    as_lists = pa.FixedSizeListArray.from_arrays(column, 1)
    table = table.set_column(table.schema.get_field_index("action"), "action", as_lists)
    pq.write_table(table, tmp_path / DATA)
    assert pq.read_schema(tmp_path / DATA).field("action").type == pa.list_(pa.float32(), 1)
    for original, read in zip(data, open_dataset(tmp_path), strict=True):
        np.testing.assert_array_equal(read.actions, original.actions)


def test_lerobots_own_reader_opens_a_1d_dataset(tmp_path):
    """Runs where lerobot is installed (it is no dependency of sb3-ef)."""
    lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")
    data = one_d_episodes()
    write_lerobot(tmp_path / "ds", data, codec="libx264rgb")
    dataset = lerobot_dataset.LeRobotDataset("local/one_d", root=tmp_path / "ds")
    assert len(dataset) == sum(episode.steps + 1 for episode in data)
    np.testing.assert_allclose(np.asarray(dataset[0]["action"]).reshape(-1), data[0].actions[0])
