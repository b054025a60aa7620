"""LeRobot datasets as ``collect`` and ``LeRobotWriter`` write them: what LeRobot reads (tasks, statistics),
several episodes per video, interrupted and continued collections, and the folders that are refused."""

from __future__ import annotations

import json
import os
import re
from fractions import Fraction

import numpy as np
import pytest

from sb3_ef.cli import main
from sb3_ef.offline.episodes import make_episode
from tests.helpers.offline import square_episode
from tests.offline.helpers import interrupt_when, run_with_file_size_limit, sb3_ef_process

av = pytest.importorskip("av")
pa = pytest.importorskip("pyarrow")
pq = pytest.importorskip("pyarrow.parquet")
pd = pytest.importorskip("pandas")

from sb3_ef.offline.lerobot import LeRobotDataset  # noqa: E402
from sb3_ef.offline.lerobot_writer import LeRobotWriter, write_lerobot  # noqa: E402

VIDEO = "videos/observation.image/chunk-000/file-000.mp4"


def episodes(count: int = 3, size: int = 32) -> list:
    return [square_episode(steps=10 + seed, size=size, seed=seed) for seed in range(count)]


def test_collect_counts_the_episodes_and_refuses_a_folder_holding_other_files(tmp_path, capsys):
    out = tmp_path / "ds"
    argv = ["collect", "toy/agent-v0", str(out), "--size", "16", "--format", "lerobot", "--no-progress"]
    assert main([*argv, "--episodes", "3"]) == 0
    assert capsys.readouterr().out.strip() == f"3 episodes in {out} (a LeRobot v3.0 dataset)"
    assert len(LeRobotDataset(out)) == 3
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    assert main(["collect", "toy/agent-v0", str(other), "--format", "lerobot", "--no-progress"]) == 2
    error = capsys.readouterr().err
    assert re.search(r"^sb3-ef collect: error: .*other is not empty \(1 files, e.g. notes.txt\)", error), error
    assert os.listdir(other) == ["notes.txt"] and (other / "notes.txt").read_text() == "mine"


def test_tasks_and_statistics_are_stored_as_lerobot_reads_them(tmp_path):
    data = episodes()
    write_lerobot(tmp_path, data, codec="libx264rgb", task="push the square")
    tasks = pd.read_parquet(tmp_path / "meta/tasks.parquet")
    tasks.index.name = "task"  # what lerobot's load_tasks does; the task string is the index
    assert tasks.iloc[0].name == "push the square" and int(tasks.loc["push the square"].task_index) == 0
    stats = {name: {k: np.asarray(v) for k, v in named.items()} for name, named in _json(tmp_path, "stats").items()}
    info = _json(tmp_path, "info")
    assert set(stats) == set(info["features"]) - {"observation.agent_mask"}
    frames = np.concatenate([episode.frames for episode in data]).astype(np.float64) / 255
    image = stats["observation.image"]
    assert all(value.shape == (3, 1, 1) for key, value in image.items() if key != "count")
    assert image["count"].tolist() == [len(frames)] == [info["total_frames"]]
    np.testing.assert_allclose(image["mean"].ravel(), frames.mean(axis=(0, 2, 3)), rtol=1e-12)
    np.testing.assert_allclose(image["std"].ravel(), frames.std(axis=(0, 2, 3)), rtol=1e-9)
    np.testing.assert_array_equal(image["max"].ravel(), frames.max(axis=(0, 2, 3)))
    actions = np.concatenate([np.r_[episode.actions, np.zeros((1, 2))] for episode in data])  # the last row: zeros
    np.testing.assert_allclose(stats["action"]["mean"], actions.mean(axis=0), rtol=1e-6)
    np.testing.assert_allclose(stats["action"]["std"], actions.std(axis=0), rtol=1e-6)
    table = pq.read_table(tmp_path / "meta/episodes/chunk-000/file-000.parquet").to_pylist()
    first = np.asarray(table[0]["stats/observation.image/q90"]).ravel()
    expected = np.quantile(data[0].frames.astype(np.float64), 0.9, axis=(0, 2, 3)) / 255
    np.testing.assert_allclose(first, expected, rtol=1e-12)  # per-episode quantiles are exact
    assert table[1]["stats/action/count"] == [len(data[1].frames)]


def _json(root, name: str) -> dict:
    return json.loads((root / "meta" / f"{name}.json").read_text())


def test_a_video_of_several_episodes_is_read_from_any_start(tmp_path):
    """Episodes that start between keyframes of a lossy video with B-frames, read in any order, give exactly the
    frames a straight decode of the whole file gives at their positions."""
    data = episodes(count=3)
    write_lerobot(tmp_path, data, codec="libx264rgb")
    video = tmp_path / VIDEO
    with av.open(str(video)) as source:
        originals = [frame.to_ndarray(format="rgb24") for frame in source.decode(video=0)]
    with av.open(str(video), "w") as container:  # H.264 with B-frames and a keyframe every 7 frames
        stream = container.add_stream("libx264", rate=10, options={"g": "7", "bf": "2", "crf": "20"})
        stream.width = stream.height = 32
        stream.pix_fmt = "yuv420p"
        for index, image in enumerate(originals):
            frame = av.VideoFrame.from_ndarray(image, "rgb24")
            frame.pts, frame.time_base = index, Fraction(1, 10)
            for packet in stream.encode(frame):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    with av.open(str(video)) as source:
        decoded = np.stack([frame.to_ndarray(format="rgb24").transpose(2, 0, 1) for frame in source.decode(video=0)])
    starts = np.cumsum([0] + [len(episode.frames) for episode in data])
    dataset = LeRobotDataset(tmp_path)
    for index in (2, 0, 1):
        np.testing.assert_array_equal(dataset[index].frames, decoded[starts[index] : starts[index + 1]])


def test_ctrl_c_leaves_a_dataset_of_the_finished_episodes_that_a_rerun_continues(tmp_path):
    out = tmp_path / "ds"
    argv = ["collect", "toy/agent-v0", str(out), "--size", "16", "--format", "lerobot", "--no-masks"]
    temporary = out / "videos/observation.image/chunk-000/.file-000.tmp.mp4"
    process = sb3_ef_process(*argv, "--episodes", "2000")
    status, err = interrupt_when(process, lambda: temporary.exists() and temporary.stat().st_size > 30_000)
    lines = [line for line in err.splitlines() if line.startswith("sb3-ef collect: interrupted")]
    assert status == 130 and "Traceback" not in err and len(lines) == 1, err
    dataset = LeRobotDataset(out)
    kept = len(dataset)
    assert f"{kept} of 2000 episodes are in {out}, a LeRobot dataset of those" in lines[0]
    assert kept >= 1 and all(len(episode.frames) == 51 for episode in dataset)  # every kept episode decodes whole
    assert not temporary.exists()
    assert main([*argv, "--episodes", str(kept + 2), "--no-progress"]) == 0
    continued = LeRobotDataset(out)
    assert len(continued) == kept + 2 and _json(out, "info")["total_episodes"] == kept + 2
    assert _json(out, "stats")["action"]["count"] == [51 * (kept + 2)]
    np.testing.assert_array_equal(continued[kept - 1].actions, dataset[kept - 1].actions)
    assert len(continued[kept + 1].frames) == 51


def test_the_writer_appends_in_new_files_and_refuses_other_settings(tmp_path):
    data = episodes(count=3)
    write_lerobot(tmp_path, data[:2], codec="libx264rgb")
    with LeRobotWriter(tmp_path, (3, 32, 32), 2, codec="libx264rgb", masks=True, append=True) as writer:
        assert writer.episodes == 2
        writer.add(data[2])
    dataset = LeRobotDataset(tmp_path)
    assert len(dataset) == 3 and (tmp_path / "data/chunk-000/file-001.parquet").is_file()
    for original, read in zip(data, dataset, strict=True):
        np.testing.assert_array_equal(read.frames, original.frames)
    with pytest.raises(ValueError, match=r"Cannot append .*: actions \[2\] \(this writer: \[3\]\); fps 10"):
        LeRobotWriter(tmp_path, (3, 32, 32), 3, fps=15, masks=True, append=True)
    with pytest.raises(FileExistsError, match="already holds a LeRobot dataset"):
        write_lerobot(tmp_path, data[:1])


def test_an_error_while_writing_keeps_a_dataset_of_the_episodes_added(tmp_path):
    data = episodes(count=2)
    odd = make_episode(data[0].frames, np.zeros((len(data[0].actions), 3), np.float32), source="odd episode")
    with pytest.raises(ValueError, match=r"odd episode: frames \(3, 32, 32\) and 3-d actions differ"):
        write_lerobot(tmp_path, [*data, odd], codec="libx264rgb")
    dataset = LeRobotDataset(tmp_path)
    assert len(dataset) == 2 and _json(tmp_path, "info")["total_episodes"] == 2
    np.testing.assert_array_equal(dataset[1].frames, data[1].frames)


@pytest.mark.parametrize("image_size", [-64, 0, True, 2.5])
def test_a_bad_image_size_is_named(tmp_path, image_size):
    write_lerobot(tmp_path, episodes(count=1), codec="libx264rgb")
    with pytest.raises(ValueError, match=rf"image_size must be a positive number of pixels .*, got {image_size!r}"):
        LeRobotDataset(tmp_path, image_size=image_size)


def test_a_full_disk_leaves_no_cut_file_and_a_rerun_writes_the_dataset(tmp_path):
    out = tmp_path / "ds"
    call = f"collect('toy/agent-v0', {str(out)!r}, episodes=6, size=16, file_format='lerobot', progress_bar=False)"
    result = run_with_file_size_limit("from sb3_ef.offline.collect import collect", call, limit=6000)
    assert result.returncode != 0 and "File too large" in result.stderr
    files = sorted(os.path.relpath(os.path.join(d, f), out) for d, _, fs in os.walk(out) for f in fs)
    assert files == ["sb3_ef_collect.json"]  # no cut video or Parquet file, no meta/ naming files that are not there
    argv = ["collect", "toy/agent-v0", str(out), "--episodes", "6", "--size", "16", "--format", "lerobot"]
    assert main([*argv, "--no-progress"]) == 0
    assert len(LeRobotDataset(out)) == 6
