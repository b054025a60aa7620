"""RLDS / TFDS shards in the layout TFDS writes (flattened ``steps/...`` features of one Example per episode)."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from sb3_ef.offline.episodes import EpisodeError, make_episode
from sb3_ef.offline.readers import open_dataset
from sb3_ef.offline.rlds import OXE_LAYOUTS, RLDSDataset
from sb3_ef.offline.tfrecord import write_records
from tests.helpers.offline import square_episode
from tests.offline.examples import serialize_example


def encode(frame: np.ndarray, image_format: str) -> bytes:
    buffer = io.BytesIO()
    Image.fromarray(frame.transpose(1, 2, 0)).save(buffer, format=image_format, quality=95)
    return buffer.getvalue()


def rlds_record(episode, image_key="observation/image", action_parts=None, image_format="PNG") -> bytes:
    """One RLDS episode as TFDS serialises it: T steps (T = frames), the last step's action padded with zeros."""
    steps = len(episode.frames)
    actions = np.r_[episode.actions, np.zeros((1, episode.action_dim), np.float32)]
    features = {
        f"steps/{image_key}": [encode(frame, image_format) for frame in episode.frames],
        "steps/observation/state": np.zeros(steps * 7, np.float32),
        "steps/is_first": np.r_[1, np.zeros(steps - 1, np.int64)],
        "steps/is_last": np.r_[np.zeros(steps - 1, np.int64), 1],
        "steps/is_terminal": np.zeros(steps, np.int64),
        "steps/reward": np.zeros(steps, np.float32),
        "steps/language_instruction": [b"push the square"] * steps,
        "episode_metadata/file_path": [b"/data/episode.h5"],
    }
    if action_parts is None:
        features["steps/action"] = actions.ravel()
    else:
        start = 0
        for name, size in action_parts:
            features[f"steps/action/{name}"] = actions[:, start : start + size].ravel()
            start += size
    return serialize_example(features)


def write_tfds_folder(root, name, records_per_shard, **kwargs):
    root.mkdir(parents=True)
    (root / "dataset_info.json").write_text(json.dumps({"name": name}))
    (root / "features.json").write_text("{}")
    for shard, records in enumerate(records_per_shard):
        path = root / f"{name}-train.tfrecord-{shard:05d}-of-{len(records_per_shard):05d}"
        write_records(path, [rlds_record(episode, **kwargs) for episode in records])


def test_rlds_folder_with_flat_actions_reads_every_episode_of_every_shard(tmp_path):
    data = [square_episode(steps=8 + seed, seed=seed) for seed in range(3)]
    root = tmp_path / "my_dataset" / "1.0.0"
    write_tfds_folder(root, "my_dataset", [data[:2], data[2:]])
    dataset = open_dataset(root)
    assert isinstance(dataset, RLDSDataset) and len(dataset) == 3 and dataset.lengths() == [9, 10, 11]
    for original, read in zip(data, dataset, strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)  # PNG: lossless
        np.testing.assert_array_equal(read.actions, original.actions)


def test_open_x_embodiment_layout_from_the_folder_name(tmp_path):
    """fractal20220817_data (RT-1): image in observation/image, the action a dict concatenated in order."""
    squares = [square_episode(steps=6, seed=seed) for seed in range(2)]
    gripper = np.linspace(-1, 1, 6, dtype=np.float32)[:, None]
    data = [make_episode(e.frames, np.c_[e.actions, gripper], source=e.source) for e in squares]
    # the 3-d actions spread over RT-1's dict parts (sized for this toy data)
    root = tmp_path / "fractal20220817_data" / "0.1.0"
    parts = [("world_vector", 1), ("rotation_delta", 1), ("gripper_closedness_action", 1)]
    write_tfds_folder(root, "fractal20220817_data", [data], image_format="JPEG", action_parts=parts)
    dataset = RLDSDataset(root)
    assert dataset.layout == "fractal20220817_data"
    for original, read in zip(data, dataset, strict=True):
        assert np.abs(read.frames.astype(int) - original.frames).mean() < 4  # JPEG, quality 95
        np.testing.assert_array_equal(read.actions, original.actions)


def test_image_and_action_keys_can_be_chosen(tmp_path):
    episode = square_episode(steps=5)
    root = tmp_path / "taco"
    write_tfds_folder(root, "taco", [[episode]], image_key="observation/rgb_static", action_parts=[("rel", 2)])
    read = RLDSDataset(root, image_key="observation/rgb_static", action_keys=["action/rel"], image_size=16)[0]
    assert read.frames.shape == (6, 3, 16, 16)
    np.testing.assert_array_equal(read.actions, episode.actions)
    with pytest.raises(EpisodeError, match=r"no image feature 'observation/image' in steps; the step features are"):
        RLDSDataset(root, image_key="observation/image")[0]
    with pytest.raises(EpisodeError, match=r"no action feature \['action/world_vector'\]"):
        RLDSDataset(root, image_key="observation/rgb_static", action_keys=["action/world_vector"])[0]
    with pytest.raises(ValueError, match="Unknown RLDS layout 'fractal'; known: "):
        RLDSDataset(root, layout="fractal")


def test_corrupt_shard_is_named_with_the_episode(tmp_path):
    root = tmp_path / "d"
    write_tfds_folder(root, "d", [[square_episode(steps=5), square_episode(steps=5, seed=1)]])
    (shard,) = root.glob("d-train.tfrecord-*")
    raw = bytearray(shard.read_bytes())
    raw[len(raw) - 40] ^= 0xFF  # inside the second record
    shard.write_bytes(bytes(raw))
    dataset = RLDSDataset(root)
    assert len(dataset[0].frames) == 6
    with pytest.raises(EpisodeError, match=r"d-train.tfrecord-00000-of-00001 \(episode 1\): .*wrong CRC-32C"):
        dataset[1]


def test_pretrain_reads_an_rlds_shard_folder_end_to_end(tmp_path):
    from sb3_ef.offline.model import load_pretrained
    from tests.helpers.offline import tiny_pretrain

    root = tmp_path / "pushes" / "1.0.0"
    write_tfds_folder(root, "pushes", [[square_episode(steps=9, seed=s) for s in range(2)], [square_episode(steps=9)]])
    _, scores = tiny_pretrain(root, tmp_path / "run", context=2)
    model, _ = load_pretrained(tmp_path / "run" / "model.pt")
    assert model.config.frame_shape == (3, 32, 32) and model.config.action_dim == 2
    assert scores["frame_mse"] > 0 and "agent_ratio" not in scores  # RLDS carries no agent masks


def test_a_record_that_is_no_example_is_named(tmp_path):
    root = tmp_path / "d"
    write_tfds_folder(root, "d", [[square_episode(steps=3)]])
    (shard,) = root.glob("d-train.tfrecord-*")
    write_records(shard, [b"\x0a\xff\x01" + b"\x00" * 10])  # valid CRCs, a message claiming 255 bytes
    with pytest.raises(EpisodeError, match=r"\(episode 0\): not a valid tf.train.Example \(ValueError: field 1 needs"):
        RLDSDataset(root)[0]


def test_a_folder_whose_shards_are_empty_is_refused_and_an_empty_shard_is_named(tmp_path):
    root = tmp_path / "d"
    write_tfds_folder(root, "d", [[square_episode(steps=3)], []])
    empty = root / "d-train.tfrecord-00001-of-00002"
    assert empty.stat().st_size == 0
    with pytest.warns(UserWarning, match=r"Empty TFRecord files \(0 bytes, no episode\) skipped: .*00001-of-00002"):
        assert len(RLDSDataset(root)) == 1
    (root / "d-train.tfrecord-00000-of-00002").write_bytes(b"")
    with pytest.raises(EpisodeError, match=r"No records in .*: 2 of 2 TFRecord files are empty \(0 bytes"):
        open_dataset(root)


def test_droid_layouts_the_dataset_action_or_octo_and_openvla_cartesian_velocity(tmp_path):
    episode = square_episode(steps=5)
    velocity = np.linspace(-1, 1, 6 * 6, dtype=np.float32).reshape(6, 6)
    gripper = np.linspace(0, 1, 6, dtype=np.float32)[:, None]  # DROID: 0 open, 1 closed
    root = tmp_path / "droid" / "1.0.0"
    root.mkdir(parents=True)
    (root / "features.json").write_text("{}")
    features = {
        "steps/observation/exterior_image_1_left": [encode(frame, "PNG") for frame in episode.frames],
        "steps/action": np.c_[velocity[:, :6], gripper].ravel(),  # 7 numbers per step
        "steps/action_dict/cartesian_velocity": velocity.ravel(),
        "steps/action_dict/gripper_position": gripper.ravel(),
        "steps/is_first": np.r_[1, np.zeros(5, np.int64)],
        "steps/is_last": np.r_[np.zeros(5, np.int64), 1],
    }
    write_records(root / "droid-train.tfrecord-00000-of-00001", [serialize_example(features)])
    dataset = RLDSDataset(root)
    assert dataset.layout == "droid" and dataset[0].action_dim == 7
    read = RLDSDataset(root, layout="droid_cartesian")[0]
    np.testing.assert_allclose(read.actions, np.c_[velocity, 1 - gripper][:5])  # the last action is dropped
    by_keys = RLDSDataset(root, action_keys=["1-action_dict/gripper_position"])[0]
    np.testing.assert_allclose(by_keys.actions, 1 - gripper[:5])
    with pytest.raises(EpisodeError, match=r"no action feature \['1-action_dict/gripper_closed'\]"):
        RLDSDataset(root, action_keys=["1-action_dict/gripper_closed"])[0]


@pytest.mark.parametrize("image_size", [0, -64])
def test_a_bad_rlds_image_size_is_named(tmp_path, image_size):
    root = tmp_path / "d"
    write_tfds_folder(root, "d", [[square_episode(steps=3)]])
    with pytest.raises(ValueError, match=rf"image_size must be a positive number of pixels .*, got {image_size}"):
        RLDSDataset(root, image_size=image_size)


def test_the_docs_list_every_layout_with_its_image_size_and_gripper():
    docs = (Path(__file__).parents[2] / "docs" / "offline.md").read_text()
    for name, (image_key, _) in OXE_LAYOUTS.items():
        row = re.search(rf"^\| `{name}`[^|]*\| `{image_key}` \| (\d+) x (\d+) \|[^|]+\|([^|]+)\|$", docs, re.M)
        assert row and row.group(3).strip(), f"{name}: no docs row with the image size and the gripper convention"
