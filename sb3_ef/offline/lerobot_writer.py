"""Episodes written as a LeRobot v3.0 dataset folder that is always one ``append=True`` continues (files renamed
into place once complete, ``meta/info.json`` last)."""

from __future__ import annotations

import json
import os
import warnings
from collections.abc import Iterable
from fractions import Fraction
from typing import Any

import numpy as np

from sb3_ef.common.files import atomic_path, refuse_files_in, temporary_path, write_text_atomically
from sb3_ef.common.interrupt import sigint_deferred
from sb3_ef.offline import lerobot_stats
from sb3_ef.offline.episodes import Episode
from sb3_ef.offline.lerobot_format import (
    INFO,
    MASK_KEY,
    STATS,
    TASKS,
    V3_DATA_PATH,
    V3_EPISODES_PATH,
    V3_VIDEO_PATH,
    lerobot_imports,
)

#: Files per chunk folder (LeRobot's default ``chunks_size``).
CHUNKS_SIZE = 1000
CODEC_NAMES = {"libsvtav1": "av1", "libx264": "h264", "libx264rgb": "h264"}
SCALARS = {"timestamp": "float32", "frame_index": "int64", "episode_index": "int64", "index": "int64"}


class _Segment:
    """One data file and one video file of consecutive episodes, under temporary names until :meth:`finish`."""

    def __init__(self, writer: LeRobotWriter, number: int):
        chunk, file = divmod(number, CHUNKS_SIZE)
        self.writer, self.number, self.location = writer, number, {"chunk_index": chunk, "file_index": file}
        self.video = os.path.join(writer.root, V3_VIDEO_PATH.format(video_key=writer.camera, **self.location))
        self.data = os.path.join(writer.root, V3_DATA_PATH.format(**self.location))
        for path in (self.video, self.data):
            os.makedirs(os.path.dirname(path), exist_ok=True)
        lossless = writer.codec == "libx264rgb"
        os.environ.setdefault("SVT_LOG", "1")  # errors only: SVT-AV1 prints its configuration per file
        self.container = writer.av.open(str(temporary_path(self.video)), "w", format="mp4")
        options = {"qp": "0"} if lossless else {"crf": str(writer.crf)}
        self.stream = self.container.add_stream(writer.codec, rate=writer.fps, options=options)
        self.stream.height, self.stream.width = writer.frame_shape[1:]
        self.stream.pix_fmt = "rgb24" if lossless else "yuv420p"
        self.stream.codec_context.gop_size = 2  # LeRobot's keyframe interval: cheap seeks to any episode
        self.frames, self.broken = 0, False
        self.tables: list[Any] = []  # of the episodes complete in the segment

    def encode(self, frames: np.ndarray) -> float:
        """Append frames (N, 3, H, W) and return the first one's time; an error marks the segment ``broken``."""
        start = self.frames / self.writer.fps
        try:
            for frame in frames:
                image = np.ascontiguousarray(frame.transpose(1, 2, 0))
                video_frame = self.writer.av.VideoFrame.from_ndarray(image, "rgb24")
                video_frame.pts, video_frame.time_base = self.frames, Fraction(1, self.writer.fps)
                for packet in self.stream.encode(video_frame):
                    self.container.mux(packet)
                self.frames += 1
        except BaseException:
            self.broken = True
            raise
        return start

    def finish(self) -> None:
        """Flush the video and write the data file, each renamed once complete; drop a segment with no episode."""
        if not self.tables:
            self.abort()
            return
        with atomic_path(self.video):  # the container writes to this temporary path
            for packet in self.stream.encode():
                self.container.mux(packet)
            self.container.close()
        schema = self.tables[0].schema
        with atomic_path(self.data) as temporary, self.writer.pq.ParquetWriter(temporary, schema) as file:
            for table in self.tables:
                file.write_table(table)  # one row group per episode

    def abort(self) -> None:
        """Close the video without keeping it."""
        try:
            self.container.close()
        finally:
            temporary_path(self.video).unlink(missing_ok=True)


class LeRobotWriter:
    """Writes episodes as a LeRobot v3.0 dataset folder (the last frame's action is zeros); see docs/offline.md.

    :param root: a new or empty folder; with ``append=True`` also a dataset this writer wrote, continued.
    :param codec: ``"libsvtav1"`` (AV1, LeRobot's default), ``"libx264"`` or ``"libx264rgb"`` (lossless).
    :param episodes_per_file: start a new data and video file every this many episodes (None: one file each).
    :param append: continue a dataset of this writer in ``root`` (same frame shape, action size, fps and masks).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        frame_shape: tuple[int, int, int],
        action_dim: int,
        fps: int = 10,
        camera: str = "observation.image",
        codec: str = "libsvtav1",
        masks: bool = False,
        task: str = "babbling",
        robot_type: str | None = None,
        episodes_per_file: int | None = None,
        crf: int = 30,
        append: bool = False,
    ):
        self.av, self.pq = lerobot_imports()
        import pyarrow as pa

        self.pa = pa
        self.root = os.fspath(root)
        channels, height, width = frame_shape
        if channels != 3 or height % 2 or width % 2:
            raise ValueError(f"Expected RGB frames (3, H, W) with even H and W for video, got {frame_shape}")
        self.frame_shape, self.action_dim, self.fps = tuple(frame_shape), action_dim, fps
        self.camera, self.codec, self.with_masks, self.task = camera, codec, masks, task
        self.episodes_per_file, self.crf, self.robot_type = episodes_per_file, crf, robot_type
        self._rows = self._existing_rows() if append else _refuse_used_folder(self.root)
        self._frames = self._rows[-1]["dataset_to_index"] if self._rows else 0
        self._next_file = 1 + max((_file_number(row, self.camera) for row in self._rows), default=-1)
        self._segment: _Segment | None = None

    @property
    def episodes(self) -> int:
        """Episodes in the dataset: those of an appended dataset and those added."""
        return len(self._rows)

    def add(self, episode: Episode) -> None:
        """Append one episode."""
        if episode.frame_shape != self.frame_shape or episode.action_dim != self.action_dim:
            raise ValueError(
                f"{episode.source}: frames {episode.frame_shape} and {episode.action_dim}-d actions differ from the "
                f"dataset's {self.frame_shape} and {self.action_dim}-d actions"
            )
        if self.with_masks and episode.masks is None:
            raise ValueError(f"{episode.source}: the dataset records agent masks and this episode has none")
        if self._segment is not None and self.episodes_per_file and len(self._segment.tables) == self.episodes_per_file:
            self._finish_segment()
        if self._segment is None:
            self._segment = _Segment(self, self._next_file)
            self._next_file += 1
        with sigint_deferred():  # the encoder emits earlier frames' packets later: a cut would lose them
            self._add(episode, self._segment)

    def _add(self, episode: Episode, segment: _Segment) -> None:
        index, length = len(self._rows), len(episode.frames)
        start = segment.encode(episode.frames)
        columns = self._columns(episode, index)
        stats = {self.camera: lerobot_stats.image_stats(episode.frames)}
        stats.update({name: lerobot_stats.vector_stats(columns[name]) for name in ("action", *SCALARS, "task_index")})
        row = {
            "episode_index": index,
            "tasks": [self.task],
            "length": length,
            **{f"data/{key}": value for key, value in segment.location.items()},
            "dataset_from_index": self._frames,
            "dataset_to_index": self._frames + length,
            **{f"videos/{self.camera}/{key}": value for key, value in segment.location.items()},
            f"videos/{self.camera}/from_timestamp": start,
            f"videos/{self.camera}/to_timestamp": segment.frames / self.fps,
            "meta/episodes/chunk_index": 0,
            "meta/episodes/file_index": 0,
            **lerobot_stats.to_columns(stats),
        }
        segment.tables.append(self._table(columns))  # the episode is complete: close() keeps it
        self._rows.append(row)
        self._frames += length

    def extend(self, episodes: Iterable[Episode]) -> LeRobotWriter:
        for episode in episodes:
            self.add(episode)
        return self

    def close(self) -> str:
        """Finish the files of the episodes added and write ``meta/``; returns the dataset folder."""
        with sigint_deferred():
            return self._close()

    def _close(self) -> str:
        self._finish_segment()
        if not self._rows:
            raise ValueError(f"No episode was added to {self.root}")
        path = os.path.join(self.root, V3_EPISODES_PATH.format(chunk_index=0, file_index=0))
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with atomic_path(path) as temporary:
            self.pq.write_table(self.pa.Table.from_pylist(self._rows), temporary)
        self._write_tasks()
        stats = lerobot_stats.aggregate([lerobot_stats.from_columns(row) for row in self._rows])
        write_text_atomically(os.path.join(self.root, STATS), json.dumps(lerobot_stats.to_json(stats), indent=4))
        write_text_atomically(os.path.join(self.root, INFO), json.dumps(self._info(), indent=4))
        return self.root

    def _finish_segment(self) -> None:
        """Finish the current files; on failure drop their episodes, so that ``meta/`` names only files there."""
        segment, self._segment = self._segment, None
        if segment is None:
            return
        with sigint_deferred():
            try:
                if not segment.broken:
                    segment.finish()
                    return
                segment.abort()
            except BaseException:
                self._drop(segment)
                raise
            self._drop(segment)

    def _drop(self, segment: _Segment) -> None:
        dropped = [row for row in self._rows if _file_number(row, self.camera) == segment.number]
        self._rows = self._rows[: len(self._rows) - len(dropped)]
        self._frames = self._rows[-1]["dataset_to_index"] if self._rows else 0
        warnings.warn(f"{len(dropped)} episodes of {self.root} were lost with a file that failed", stacklevel=4)

    def _columns(self, episode: Episode, index: int) -> dict[str, np.ndarray]:
        length = len(episode.frames)
        actions = np.zeros((length, self.action_dim), np.float32)
        actions[: episode.steps] = episode.actions
        columns = {
            "action": actions,
            "timestamp": np.arange(length, dtype=np.float32) / np.float32(self.fps),
            "frame_index": np.arange(length, dtype=np.int64),
            "episode_index": np.full(length, index, dtype=np.int64),
            "index": np.arange(self._frames, self._frames + length, dtype=np.int64),
            "task_index": np.zeros(length, dtype=np.int64),
        }
        if self.with_masks:
            columns[MASK_KEY] = episode.masks  # type: ignore[assignment]
        return columns

    def _table(self, columns: dict[str, np.ndarray]) -> Any:
        """Parquet columns: fixed-size lists for actions and masks; a 1-d action is a float column (LeRobot's way)."""
        pa = self.pa
        arrays = {name: pa.array(values) for name, values in columns.items() if values.ndim == 1}
        actions = columns["action"]
        if self.action_dim == 1:
            arrays["action"] = pa.array(actions[:, 0])
        else:
            arrays["action"] = pa.FixedSizeListArray.from_arrays(pa.array(actions.ravel()), self.action_dim)
        if MASK_KEY in columns:
            height, width = self.frame_shape[1:]
            rows = pa.FixedSizeListArray.from_arrays(pa.array(columns[MASK_KEY].ravel()), width)
            arrays[MASK_KEY] = pa.FixedSizeListArray.from_arrays(rows, height)
        return pa.table({name: arrays[name] for name in columns})

    def _write_tasks(self) -> None:
        """``meta/tasks.parquet`` as LeRobot writes it: the task string is the pandas index, ``task_index`` a column."""
        import pandas as pd

        tasks = pd.DataFrame({"task_index": [0]}, index=pd.Index([self.task], name="task"))
        with atomic_path(os.path.join(self.root, TASKS)) as temporary:
            tasks.to_parquet(temporary)

    def _features(self) -> dict[str, Any]:
        height, width = self.frame_shape[1:]
        video = {"video.height": height, "video.width": width, "video.codec": CODEC_NAMES.get(self.codec, self.codec)}
        video.update({"video.pix_fmt": "rgb24" if self.codec == "libx264rgb" else "yuv420p"})
        video.update({"video.is_depth_map": False, "video.fps": self.fps, "video.channels": 3, "has_audio": False})
        features: dict[str, Any] = {
            self.camera: {"dtype": "video", "shape": [height, width, 3], "names": ["height", "width", "channels"]},
            "action": {"dtype": "float32", "shape": [self.action_dim], "names": None},
        }
        features[self.camera]["info"] = video
        if self.with_masks:
            features[MASK_KEY] = {"dtype": "bool", "shape": [height, width], "names": ["height", "width"]}
        for name, dtype in {**SCALARS, "task_index": "int64"}.items():
            features[name] = {"dtype": dtype, "shape": [1], "names": None}
        return features

    def _info(self) -> dict[str, Any]:
        return {
            "codebase_version": "v3.0",
            "robot_type": self.robot_type,
            "total_episodes": len(self._rows),
            "total_frames": self._frames,
            "total_tasks": 1,
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": 100,
            "video_files_size_in_mb": 200,
            "fps": self.fps,
            "splits": {"train": f"0:{len(self._rows)}"},
            "data_path": V3_DATA_PATH,
            "video_path": V3_VIDEO_PATH,
            "features": self._features(),
        }

    def _existing_rows(self) -> list[dict[str, Any]]:
        """The episode table of the dataset ``append`` continues, checked against the writer's settings."""
        if not os.path.isfile(os.path.join(self.root, INFO)):
            return []
        with open(os.path.join(self.root, INFO)) as file:
            info = json.load(file)
        differences = [
            f"{name} {theirs} (this writer: {ours})"
            for name, theirs, ours in (
                ("frames", info["features"].get(self.camera, {}).get("shape"), [*self.frame_shape[1:], 3]),
                ("actions", info["features"].get("action", {}).get("shape"), [self.action_dim]),
                ("fps", info["fps"], self.fps),
                ("agent masks", MASK_KEY in info["features"], self.with_masks),
            )
            if theirs != ours
        ]
        path = os.path.join(self.root, V3_EPISODES_PATH.format(chunk_index=0, file_index=0))
        rows = self.pq.read_table(path).to_pylist() if os.path.isfile(path) else []
        if not rows or not any(column.startswith("stats/") for column in rows[0]):
            differences.append("no per-episode statistics in meta/episodes (not written by LeRobotWriter)")
        if differences:
            raise ValueError(f"Cannot append to the LeRobot dataset in {self.root}: {'; '.join(differences)}")
        return sorted(rows, key=lambda row: row["episode_index"])

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(self, *exc_info: Any) -> None:
        if exc_info[0] is None:
            self.close()
            return
        try:  # keep the episodes added so far, for append=True
            if self._rows:
                self.close()
            elif self._segment is not None:
                self._segment.abort()
        except Exception as error:
            if self._segment is not None:
                self._segment.abort()
            warnings.warn(f"Could not finish the LeRobot dataset in {self.root} ({error})", stacklevel=2)


def _file_number(row: dict[str, Any], camera: str) -> int:
    data = row["data/chunk_index"] * CHUNKS_SIZE + row["data/file_index"]
    video = row[f"videos/{camera}/chunk_index"] * CHUNKS_SIZE + row[f"videos/{camera}/file_index"]
    return max(data, video)


def _refuse_used_folder(root: str) -> list[dict[str, Any]]:
    """No episode rows, once ``root`` is known to be new or empty."""
    if os.path.isfile(os.path.join(root, INFO)):
        raise FileExistsError(f"{root} already holds a LeRobot dataset ({INFO}); write to another folder")
    refuse_files_in(root, ": a LeRobot dataset is written into a new or empty folder")
    return []


def write_lerobot(root: str | os.PathLike, episodes: list[Episode], **kwargs: Any) -> str:
    """Write ``episodes`` as a LeRobot v3.0 dataset (see :class:`LeRobotWriter` for the options)."""
    if not episodes:
        raise ValueError("No episodes to write")
    first = episodes[0]
    kwargs.setdefault("masks", all(episode.masks is not None for episode in episodes))
    with LeRobotWriter(root, first.frame_shape, first.action_dim, **kwargs) as writer:
        writer.extend(episodes)
    return os.fspath(root)
