"""LeRobot datasets: real Parquet tables and MP4 videos in the v3.0 (and v2.1) layout, read back; damaged files."""

from __future__ import annotations

import json
import os
import re
from fractions import Fraction

import numpy as np
import pytest

from sb3_ef.offline.episodes import EpisodeError
from tests.helpers.offline import square_episode

av = pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")

from sb3_ef.offline.lerobot import LeRobotDataset, write_lerobot  # noqa: E402
from sb3_ef.offline.readers import open_dataset  # noqa: E402


def has_encoder(name: str) -> bool:
    try:
        av.codec.Codec(name, "w")
    except Exception:  # PyAV raises UnknownCodecError or ValueError, by version
        return False
    return True


def episodes(count: int = 3, size: int = 32) -> list:
    return [square_episode(steps=10 + seed, size=size, seed=seed) for seed in range(count)]


def test_lossless_v3_round_trip_is_exact_across_files(tmp_path):
    data = episodes()
    write_lerobot(tmp_path, data, codec="libx264rgb", episodes_per_file=2, fps=15)
    files = sorted(os.path.relpath(os.path.join(d, f), tmp_path) for d, _, fs in os.walk(tmp_path) for f in fs)
    assert files == [
        "data/chunk-000/file-000.parquet",
        "data/chunk-000/file-001.parquet",
        "meta/episodes/chunk-000/file-000.parquet",
        "meta/info.json",
        "meta/stats.json",
        "meta/tasks.parquet",
        "videos/observation.image/chunk-000/file-000.mp4",
        "videos/observation.image/chunk-000/file-001.mp4",
    ]
    table = pq.read_table(tmp_path / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    assert [row["length"] for row in table] == [11, 12, 13]
    assert table[1]["videos/observation.image/from_timestamp"] == pytest.approx(11 / 15)  # second in its video
    dataset = open_dataset(tmp_path)
    assert isinstance(dataset, LeRobotDataset) and len(dataset) == 3 and dataset.lengths() == [11, 12, 13]
    for original, read in zip(data, dataset, strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)
        np.testing.assert_array_equal(read.actions, original.actions)
        np.testing.assert_array_equal(read.masks, original.masks)


@pytest.mark.parametrize("codec", ["libsvtav1", "libx264"])
def test_av1_and_h264_videos_decode_close_to_the_frames(tmp_path, codec):
    if not has_encoder(codec):
        pytest.skip(f"this FFmpeg build has no {codec} encoder")
    data = episodes(count=2)
    write_lerobot(tmp_path, data, codec=codec)
    info = json.loads((tmp_path / "meta/info.json").read_text())
    assert info["features"]["observation.image"]["info"]["video.codec"] == {"libsvtav1": "av1"}.get(codec, "h264")
    for original, read in zip(data, LeRobotDataset(tmp_path), strict=True):
        assert read.frames.shape == original.frames.shape
        # yuv420p halves the colour resolution: the square's red edges blur, the rest is within a few levels
        assert np.abs(read.frames.astype(int) - original.frames).mean() < 6
        np.testing.assert_array_equal(read.actions, original.actions)


def test_frames_are_resized_to_the_requested_size(tmp_path):
    write_lerobot(tmp_path, episodes(count=1, size=32), codec="libx264rgb")
    read = LeRobotDataset(tmp_path, image_size=16)[0]
    assert read.frames.shape == (11, 3, 16, 16) and read.masks.shape == (11, 16, 16)


def _write_v21(root, data, fps=10):
    """A v2.1 dataset: one Parquet file and one MP4 per episode, meta/episodes.jsonl, paths from episode_chunk."""
    info = {
        "codebase_version": "v2.1",
        "fps": fps,
        "chunks_size": 1000,
        "data_path": "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet",
        "video_path": "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4",
        "features": {
            "observation.images.top": {"dtype": "video", "shape": [32, 32, 3]},
            "action": {"dtype": "float32", "shape": [2]},
        },
    }
    os.makedirs(root / "meta")
    (root / "meta/info.json").write_text(json.dumps(info))
    with open(root / "meta/episodes.jsonl", "w") as file:
        for index, episode in enumerate(data):
            file.write(json.dumps({"episode_index": index, "tasks": ["push"], "length": len(episode.frames)}) + "\n")
    for index, episode in enumerate(data):
        length = len(episode.frames)
        actions = np.r_[episode.actions, np.zeros((1, 2), np.float32)]
        os.makedirs(root / "data/chunk-000", exist_ok=True)
        pq.write_table(
            pa.table(
                {
                    "action": [list(row) for row in actions],
                    "timestamp": np.arange(length, dtype=np.float32) / fps,
                    "frame_index": np.arange(length),
                    "episode_index": np.full(length, index),
                }
            ),
            root / f"data/chunk-000/episode_{index:06d}.parquet",
        )
        video = root / f"videos/chunk-000/observation.images.top/episode_{index:06d}.mp4"
        os.makedirs(video.parent, exist_ok=True)
        with av.open(str(video), "w") as container:
            stream = container.add_stream("libx264rgb", rate=fps, options={"qp": "0"})
            stream.width = stream.height = 32
            stream.pix_fmt = "rgb24"
            for t, frame in enumerate(episode.frames):
                video_frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame.transpose(1, 2, 0)), "rgb24")
                video_frame.pts, video_frame.time_base = t, Fraction(1, fps)
                for packet in stream.encode(video_frame):
                    container.mux(packet)
            for packet in stream.encode():
                container.mux(packet)


def test_v21_layout_one_file_per_episode(tmp_path):
    data = episodes(count=2)
    _write_v21(tmp_path, data)
    dataset = LeRobotDataset(tmp_path)
    assert dataset.camera == "observation.images.top" and dataset.mask_key is None
    for original, read in zip(data, dataset, strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)
        np.testing.assert_array_equal(read.actions, original.actions)


def test_image_cameras_stored_in_the_parquet_table(tmp_path):
    """A camera of dtype "image": PNG bytes per row, in the struct {bytes, path} LeRobot writes."""
    import io

    from PIL import Image

    data = episodes(count=2)
    _write_v21(tmp_path, data)
    info = json.loads((tmp_path / "meta/info.json").read_text())
    info["features"]["observation.images.top"]["dtype"] = "image"
    (tmp_path / "meta/info.json").write_text(json.dumps(info))
    for index, episode in enumerate(data):
        path = tmp_path / f"data/chunk-000/episode_{index:06d}.parquet"
        pngs = []
        for frame in episode.frames:
            buffer = io.BytesIO()
            Image.fromarray(frame.transpose(1, 2, 0)).save(buffer, format="PNG")
            pngs.append({"bytes": buffer.getvalue(), "path": None})
        table = pq.read_table(path).append_column("observation.images.top", pa.array(pngs))
        pq.write_table(table, path)
    for original, read in zip(data, LeRobotDataset(tmp_path), strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)
        np.testing.assert_array_equal(read.actions, original.actions)


def test_unknown_camera_or_action_lists_what_exists(tmp_path):
    write_lerobot(tmp_path, episodes(count=1), codec="libx264rgb")
    with pytest.raises(EpisodeError, match=r"no camera 'wrist'; the cameras are \['observation.image'\]"):
        LeRobotDataset(tmp_path, camera="wrist")
    with pytest.raises(EpisodeError, match=r"no action feature 'act'; numeric features: \['action'"):
        LeRobotDataset(tmp_path, action_key="act")


def test_truncated_video_names_file_episode_expected_and_found(tmp_path):
    write_lerobot(tmp_path, episodes(count=2), codec="libx264rgb")
    video = tmp_path / "videos/observation.image/chunk-000/file-000.mp4"
    video.write_bytes(video.read_bytes()[: video.stat().st_size // 2])
    with pytest.raises(EpisodeError, match=r"file-000.mp4 \(episode 0\): cannot decode the video"):
        LeRobotDataset(tmp_path)[0]


def test_video_shorter_than_the_episode_table(tmp_path):
    data = episodes(count=2)
    write_lerobot(tmp_path, data, codec="libx264rgb")
    shorter = tmp_path / "short"
    write_lerobot(shorter, [data[0], square_episode(steps=5, seed=9)], codec="libx264rgb")
    (tmp_path / "videos/observation.image/chunk-000/file-000.mp4").write_bytes(
        (shorter / "videos/observation.image/chunk-000/file-000.mp4").read_bytes()
    )  # a valid MP4 that ends 6 frames early
    np.testing.assert_array_equal(LeRobotDataset(tmp_path)[0].frames, data[0].frames)
    with pytest.raises(EpisodeError, match=r"\(episode 1\): expected 12 frames at 1.100-2.200 s, found 6"):
        LeRobotDataset(tmp_path)[1]


def test_corrupt_parquet_and_missing_rows(tmp_path):
    write_lerobot(tmp_path, episodes(count=2), codec="libx264rgb")
    data = tmp_path / "data/chunk-000/file-000.parquet"
    raw = data.read_bytes()
    data.write_bytes(raw[:100] + b"\x00" * 200 + raw[300:])
    with pytest.raises(EpisodeError, match=r"file-000.parquet \(episode 0\): cannot read Parquet file"):
        LeRobotDataset(tmp_path)[0]
    data.write_bytes(raw)
    table = pq.read_table(tmp_path / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    table[1]["length"] = 13
    pq.write_table(pa.Table.from_pylist(table), tmp_path / "meta/episodes/chunk-000/file-000.parquet")
    with pytest.raises(EpisodeError, match=r"\(episode 1\): expected 13 rows \(the episode's length\), found 12"):
        LeRobotDataset(tmp_path)[1]
    episodes_table = tmp_path / "meta/episodes/chunk-000/file-000.parquet"
    pq.write_table(pq.read_table(episodes_table).drop_columns(["data/file_index"]), episodes_table)
    with pytest.raises(
        EpisodeError, match=r"file-000.parquet \(episode table\): missing columns \['data/file_index'\]"
    ):
        LeRobotDataset(tmp_path)


def test_info_json_without_fps_is_named(tmp_path):
    write_lerobot(tmp_path, episodes(count=1), codec="libx264rgb")
    info = json.loads((tmp_path / "meta/info.json").read_text())
    del info["fps"]
    (tmp_path / "meta/info.json").write_text(json.dumps(info))
    with pytest.raises(EpisodeError, match=r"info.json: missing \['fps'\] \(a LeRobot v3.0 info.json has them\)"):
        LeRobotDataset(tmp_path)


def test_writer_refuses_an_existing_dataset(tmp_path):
    write_lerobot(tmp_path, episodes(count=1), codec="libx264rgb")
    with pytest.raises(FileExistsError, match="already holds a LeRobot dataset"):
        write_lerobot(tmp_path, episodes(count=1), codec="libx264rgb")


def test_pretrain_and_predict_read_a_lerobot_dataset_end_to_end(tmp_path, capsys):
    from sb3_ef.cli import main

    write_lerobot(tmp_path / "ds", episodes(count=3, size=64), codec="libsvtav1", robot_type="square")
    arguments = ["--encoder", "drqv2", "--context", "2", "--horizon", "3", "--steps", "2", "--batch-size", "4"]
    arguments += ["--holdout", "1", "--encoder-kwargs", '{"features_dim": 64}', "--agent-dim", "8", "--no-progress"]
    arguments += ["--camera", "observation.image", "--image-size", "32"]
    assert main(["pretrain", str(tmp_path / "ds"), str(tmp_path / "run"), *arguments]) == 0
    assert '"agent_ratio"' in capsys.readouterr().out  # masks travel through the Parquet table
    metrics = json.loads((tmp_path / "run/metrics.json").read_text())
    assert metrics["train_episodes"] == 2 and metrics["held_out_episodes"] == 1
    predict = ["predict", str(tmp_path / "run/model.pt"), str(tmp_path / "pred"), "--dataset", str(tmp_path / "ds")]
    assert main([*predict, "--episode", "2", "--image-size", "32"]) == 0
    assert (tmp_path / "pred/prediction.png").is_file()
    assert main(["pretrain", str(tmp_path / "ds"), str(tmp_path / "run2"), "--image-key", "observation/image"]) == 2
    error = capsys.readouterr().err
    assert re.search(
        r"^sb3-ef pretrain: error: --image-key applies to RLDS folders only; .*ds is a LeRobot dataset", error
    )
    assert not (tmp_path / "run2").exists()
