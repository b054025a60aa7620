"""Every reader on small files written in its real format, and the errors for bad data."""

from __future__ import annotations

import io
import os

import numpy as np
import pytest
from PIL import Image

from sb3_ef.offline.episodes import EpisodeError, make_episode, write_episode
from sb3_ef.offline.readers import BAIRDataset, FolderDataset, load_episodes, open_dataset
from sb3_ef.offline.tfrecord import parse_example, write_records
from tests.helpers.offline import square_episode
from tests.offline.examples import serialize_example


@pytest.mark.parametrize("suffix", ["npz", "h5"])
def test_folder_round_trip(tmp_path, suffix):
    episodes = [square_episode(steps=12, seed=seed) for seed in range(3)]
    for index, episode in enumerate(episodes):
        write_episode(tmp_path / f"episode_{index}.{suffix}", episode)
    dataset = open_dataset(tmp_path)
    assert isinstance(dataset, FolderDataset) and len(dataset) == 3
    for original, read in zip(episodes, load_episodes(dataset), strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)
        np.testing.assert_array_equal(read.actions, original.actions)
        np.testing.assert_array_equal(read.masks, original.masks)
        assert read.frames.dtype == np.uint8 and read.masks.dtype == bool


def test_t_frames_for_t_actions_drop_the_last_action():
    episode = square_episode(steps=6)
    read = make_episode(episode.frames[:-1], episode.actions, episode.masks[:-1])
    assert read.steps == 5 and len(read.frames) == 6
    np.testing.assert_array_equal(read.actions, episode.actions[:5])


def _write_arrays(path, **arrays):
    np.savez(path, **arrays)
    return str(path)


@pytest.mark.parametrize(
    "arrays, match",
    [
        ({"actions": np.zeros((5, 2))}, r"missing \['frames'\]"),
        ({"frames": np.zeros((6, 3, 8, 8)), "actions": np.zeros((5, 2))}, "expected uint8 frames.*float64"),
        ({"frames": np.zeros((9, 3, 8, 8), np.uint8), "actions": np.zeros((5, 2))}, "9 frames and 5 actions"),
        ({"frames": np.zeros((6, 8, 8, 3), np.uint8), "actions": np.zeros((5, 2))}, r"\(T \+ 1, 3, height, width\)"),
        ({"frames": np.zeros((4, 3, 8, 8), np.uint8), "actions": np.zeros((3, 2))}, "shorter than context \\+ horizon"),
        (
            {"frames": np.zeros((6, 3, 8, 8), np.uint8), "actions": np.zeros((5, 2)), "masks": np.zeros((6, 4, 4))},
            r"masks of shape \(6, 8, 8\)",
        ),
    ],
)
def test_bad_folder_episodes_name_file_episode_and_expectation(tmp_path, arrays, match):
    path = _write_arrays(tmp_path / "episode_0.npz", **arrays)
    with pytest.raises(EpisodeError, match=match) as error:
        FolderDataset(tmp_path, min_frames=5)[0]
    assert path in str(error.value) and "(episode 0)" in str(error.value)


def test_episodes_of_different_shapes_are_refused(tmp_path):
    write_episode(tmp_path / "a.npz", square_episode(size=32))
    write_episode(tmp_path / "b.npz", square_episode(size=16))
    with pytest.raises(EpisodeError, match="differ from"):
        load_episodes(FolderDataset(tmp_path))


def _bair_record(frames: np.ndarray, actions: np.ndarray, encode: str = "raw") -> bytes:
    """One episode in softmotion30_44k's layout: per step the aux1 image, the action and the end-effector position."""
    features = {}
    for step, (frame, action) in enumerate(zip(frames, actions, strict=True)):
        image = frame.transpose(1, 2, 0)
        if encode == "raw":
            data = image.tobytes()
        else:
            buffer = io.BytesIO()
            Image.fromarray(image).save(buffer, format="PNG")
            data = buffer.getvalue()
        features[f"{step}/image_aux1/encoded"] = [data]
        features[f"{step}/image_main/encoded"] = [data]
        features[f"{step}/action"] = action
        features[f"{step}/endeffector_pos"] = np.array([0.1, 0.2, step], dtype=np.float32)
    return serialize_example(features)


@pytest.mark.parametrize("encode", ["raw", "png"])
def test_bair_layout_is_read_without_tensorflow(tmp_path, encode):
    rng = np.random.default_rng(0)
    episodes = [
        (rng.integers(0, 256, (30, 3, 64, 64), dtype=np.uint8), rng.uniform(-1, 1, (30, 4)).astype(np.float32))
        for _ in range(3)
    ]
    write_records(tmp_path / "traj_0_to_1.tfrecords", [_bair_record(*e, encode) for e in episodes[:2]])
    write_records(tmp_path / "traj_2_to_2.tfrecords", [_bair_record(*episodes[2], encode)])
    dataset = open_dataset(tmp_path)
    assert isinstance(dataset, BAIRDataset) and len(dataset) == 3
    for (frames, actions), read in zip(episodes, dataset, strict=True):
        np.testing.assert_array_equal(read.frames, frames)
        np.testing.assert_array_equal(read.actions, actions[:-1])  # 30 frames, 30 actions: the last has no frame
        assert read.masks is None


def test_bair_missing_step_feature_is_named(tmp_path):
    frames = np.zeros((5, 3, 64, 64), np.uint8)
    record = _bair_record(frames, np.zeros((5, 4), np.float32))
    features = parse_example(record)
    del features["3/action"]
    path = tmp_path / "bad.tfrecord"
    write_records(path, [serialize_example(features)])
    with pytest.raises(EpisodeError, match=r"bad.tfrecord \(episode 0\): missing feature '3/action'"):
        BAIRDataset(path)[0]


def test_minari_dataset_written_with_minari(tmp_path, monkeypatch):
    minari = pytest.importorskip("minari")
    import gymnasium as gym
    from minari.data_collector import EpisodeBuffer

    from sb3_ef.offline.readers import MinariDataset

    monkeypatch.setenv("MINARI_DATASETS_PATH", os.fspath(tmp_path))
    episodes = [square_episode(steps=8, seed=seed) for seed in range(2)]
    buffers = [
        EpisodeBuffer(
            id=index,
            observations=episode.frames.transpose(0, 2, 3, 1),  # Gymnasium images are channels-last
            actions=episode.actions,
            rewards=np.zeros(episode.steps),
            terminations=np.zeros(episode.steps, bool),
            truncations=np.r_[np.zeros(episode.steps - 1, bool), True],
            infos={"agent_mask": episode.masks},
        )
        for index, episode in enumerate(episodes)
    ]
    with pytest.warns(UserWarning):
        minari.create_dataset_from_buffers(
            "sb3ef/squares-v0",
            buffers,
            observation_space=gym.spaces.Box(0, 255, (32, 32, 3), np.uint8),
            action_space=gym.spaces.Box(-1, 1, (2,), np.float32),
            algorithm_name="babbling",
        )
    dataset = open_dataset("minari:sb3ef/squares-v0")
    assert isinstance(dataset, MinariDataset) and len(dataset) == 2
    for original, read in zip(episodes, dataset, strict=True):
        # Minari stores image observations as JPEG: lossy, so compare closely rather than exactly.
        assert read.frames.shape == original.frames.shape and read.frames.dtype == np.uint8
        assert np.abs(read.frames.astype(int) - original.frames).mean() < 8
        np.testing.assert_array_equal(read.actions, original.actions)
        np.testing.assert_array_equal(read.masks, original.masks)


def test_bair_random_access_checks_crcs_unless_told_not_to(tmp_path):
    frames = np.full((4, 3, 64, 64), 7, np.uint8)
    path = tmp_path / "a.tfrecord"
    write_records(path, [_bair_record(frames, np.zeros((4, 4), np.float32))])
    raw = bytearray(path.read_bytes())
    position = raw.index(bytes([7] * 64)) + 10  # inside the first frame's pixels
    raw[position] = 8
    path.write_bytes(bytes(raw))
    with pytest.raises(EpisodeError, match=r"a.tfrecord \(episode 0\): .*wrong CRC-32C"):
        BAIRDataset(path)[0]
    read = BAIRDataset(path, verify=False)[0]
    assert (read.frames != 7).sum() == 1  # the flipped byte is read as it is


def test_truncated_tfrecord_is_an_episode_error_naming_the_record(tmp_path):
    path = tmp_path / "a.tfrecord"
    write_records(path, [_bair_record(np.zeros((4, 3, 64, 64), np.uint8), np.zeros((4, 4), np.float32))])
    path.write_bytes(path.read_bytes()[:-100])
    with pytest.raises(EpisodeError, match=r"a.tfrecord: record 0 is truncated \(expected \d+ data bytes"):
        open_dataset(path)


def test_a_folder_mixing_frame_sizes_raises_when_iterated_or_indexed(tmp_path):
    write_episode(tmp_path / "a.npz", square_episode(size=32))
    write_episode(tmp_path / "b.npz", square_episode(size=16))
    dataset = FolderDataset(tmp_path)
    with pytest.raises(
        EpisodeError, match=r"b.npz \(episode 1\): frames of shape \(3, 16, 16\) .* differ from .*a.npz"
    ):
        dataset.lengths()  # from the file headers, before any frame is decompressed
    with pytest.raises(EpisodeError, match=r"b.npz \(episode 1\): frames \(3, 16, 16\) and 2-d actions differ from"):
        list(dataset)
    reversed_order = FolderDataset(tmp_path)
    reversed_order[1]
    with pytest.raises(EpisodeError, match=r"a.npz \(episode 0\): frames \(3, 32, 32\) .* differ from .*b.npz"):
        reversed_order[0]


def test_a_single_npy_array_named_npz_is_named(tmp_path):
    np.save(tmp_path / "array.npy", np.zeros((4, 3, 8, 8), np.uint8))
    os.rename(tmp_path / "array.npy", tmp_path / "episode_0.npz")
    with pytest.raises(EpisodeError, match=r"episode_0.npz \(episode 0\): a single .npy array, not an .npz archive"):
        FolderDataset(tmp_path)[0]


def test_a_bad_bair_image_size_is_named(tmp_path):
    path = tmp_path / "a.tfrecord"
    write_records(path, [_bair_record(np.zeros((4, 3, 64, 64), np.uint8), np.zeros((4, 4), np.float32))])
    with pytest.raises(ValueError, match=r"image_size must be a positive number of pixels \(frames of N x N\), got 0"):
        BAIRDataset(path, image_size=0)
