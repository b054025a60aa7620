"""LeRobot datasets (v3.0 and v2.x) read with pyarrow and PyAV, without the ``lerobot`` package and its dependencies."""

from __future__ import annotations

import glob
import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from sb3_ef.offline.dataset import EpisodeDataset, check_image_size, decode_image
from sb3_ef.offline.episodes import Episode, EpisodeError, make_episode
from sb3_ef.offline.lerobot_format import (
    INFO,
    MASK_KEY,
    V3_DATA_PATH,
    V3_VIDEO_PATH,
    VIDEO_COLUMNS,
    is_lerobot_dataset,
    lerobot_imports,
)
from sb3_ef.offline.lerobot_writer import LeRobotWriter, write_lerobot

__all__ = ["MASK_KEY", "LeRobotDataset", "LeRobotWriter", "is_lerobot_dataset", "write_lerobot"]


class LeRobotDataset(EpisodeDataset):
    """Episodes of a local LeRobot dataset folder: one camera's frames (video or image) and the actions.

    :param root: the dataset folder (holding ``meta/info.json``).
    :param camera: the camera feature, e.g. ``"observation.images.top"`` (default: the first video or image one).
    :param action_key: the action feature (a float vector per frame).
    :param image_size: resize frames to ``image_size`` squared (None: keep the camera's size).
    :param mask_key: a per-frame boolean (height, width) agent-mask feature (default: ``MASK_KEY`` if present).
    """

    def __init__(
        self,
        root: str | os.PathLike,
        camera: str | None = None,
        action_key: str = "action",
        image_size: int | None = None,
        mask_key: str | None = None,
        min_frames: int = 2,
    ):
        super().__init__(min_frames)
        self._av, self._pq = lerobot_imports()
        self.image_size = check_image_size(image_size)
        self.root = os.fspath(root)
        info_path = os.path.join(self.root, INFO)
        if not os.path.isfile(info_path):
            raise FileNotFoundError(f"{self.root!r} is not a LeRobot dataset: no {INFO}")
        try:
            self.info = json.loads(Path(info_path).read_text())
        except json.JSONDecodeError as error:
            raise EpisodeError(f"{info_path}: not valid JSON ({error})") from error
        self.version = str(self.info.get("codebase_version", ""))
        if not self.version.startswith(("v2", "v3")):
            raise EpisodeError(f"{info_path}: expected codebase_version v2.x or v3.x, got {self.version!r}")
        required = ("fps", "features") + (("data_path",) if self.version.startswith("v2") else ())
        missing = [key for key in required if key not in self.info]
        if missing:
            raise EpisodeError(f"{info_path}: missing {missing} (a LeRobot {self.version} info.json has them)")
        features, cameras = self.info["features"], self.cameras
        if not cameras:
            raise EpisodeError(f"{info_path}: no video or image feature (features: {sorted(features)})")
        self.camera = camera or cameras[0]
        if self.camera not in cameras:
            raise EpisodeError(f"{info_path}: no camera {self.camera!r}; the cameras are {cameras}")
        if action_key not in features:
            numeric = [k for k, f in features.items() if f.get("dtype", "").startswith(("float", "int"))]
            raise EpisodeError(f"{info_path}: no action feature {action_key!r}; numeric features: {numeric}")
        self.action_key = action_key
        self.mask_key = mask_key if mask_key is not None else (MASK_KEY if MASK_KEY in features else None)
        if self.mask_key is not None and self.mask_key not in features:
            raise EpisodeError(f"{info_path}: no mask feature {self.mask_key!r} (features: {sorted(features)})")
        self.is_video = features[self.camera]["dtype"] == "video"
        self.fps = float(self.info["fps"])
        self.episodes = self._read_episode_index()

    @property
    def cameras(self) -> list[str]:
        return [k for k, f in self.info["features"].items() if f.get("dtype") in ("video", "image")]

    def __len__(self) -> int:
        return len(self.episodes)

    def lengths(self) -> list[int]:
        return [int(episode["length"]) for episode in self.episodes]

    def _read_episode_index(self) -> list[dict[str, Any]]:
        if self.version.startswith("v3"):
            paths = sorted(glob.glob(os.path.join(self.root, "meta", "episodes", "*", "*.parquet")))
            if not paths:
                raise EpisodeError(f"{self.root}: no meta/episodes/chunk-*/file-*.parquet episode tables")
            # only the columns used here: real episode tables also hold per-episode statistics of every feature
            wanted = ["episode_index", "length", "data/chunk_index", "data/file_index"]
            wanted += [f"videos/{self.camera}/{key}" for key in VIDEO_COLUMNS] if self.is_video else []
            rows = []
            for path in paths:
                try:
                    present = set(self._pq.read_schema(path).names)
                except Exception as error:  # pyarrow raises ArrowInvalid / OSError subclasses for damaged files
                    raise EpisodeError(f"{path} (episode table): cannot read Parquet file {path}: {error}") from error
                missing = [column for column in wanted if column not in present]
                if missing:
                    raise EpisodeError(f"{path} (episode table): missing columns {missing}")
                rows += self._read_table(path, wanted, f"{path} (episode table)").to_pylist()
        else:
            path = os.path.join(self.root, "meta", "episodes.jsonl")
            try:
                with open(path) as file:
                    rows = [json.loads(line) for line in file if line.strip()]
            except (OSError, json.JSONDecodeError) as error:
                raise EpisodeError(f"{path}: cannot read the episode list ({error})") from error
        rows.sort(key=lambda row: row["episode_index"])
        for row in rows:
            if "length" not in row:
                raise EpisodeError(f"{self.root}: episode {row.get('episode_index')} has no 'length' in its metadata")
        return rows

    def _read_table(self, path: str, columns: list[str] | None, source: str, filters: Any = None) -> Any:
        try:
            return self._pq.read_table(path, columns=columns, filters=filters)
        except FileNotFoundError as error:
            raise EpisodeError(f"{source}: file {path} is missing") from error
        except Exception as error:  # pyarrow raises ArrowInvalid / OSError subclasses for damaged files
            raise EpisodeError(f"{source}: cannot read Parquet file {path}: {error}") from error

    def _paths(self, episode: dict[str, Any]) -> tuple[str, str | None, float]:
        """Data file, video file (None for image cameras) and the episode's start time in the video."""
        index = int(episode["episode_index"])
        if self.version.startswith("v3"):
            data = self.info.get("data_path", V3_DATA_PATH).format(
                chunk_index=episode["data/chunk_index"], file_index=episode["data/file_index"]
            )
            video, start = None, 0.0
            if self.is_video:
                prefix = f"videos/{self.camera}/"
                video = self.info.get("video_path", V3_VIDEO_PATH).format(
                    video_key=self.camera,
                    chunk_index=episode[prefix + "chunk_index"],
                    file_index=episode[prefix + "file_index"],
                )
                start = float(episode[prefix + "from_timestamp"])
        else:
            chunk = index // int(self.info.get("chunks_size", 1000))
            data = self.info["data_path"].format(episode_chunk=chunk, episode_index=index)
            video = (
                self.info["video_path"].format(episode_chunk=chunk, episode_index=index, video_key=self.camera)
                if self.is_video
                else None
            )
            start = 0.0
        return os.path.join(self.root, data), (os.path.join(self.root, video) if video else None), start

    def _read(self, index: int) -> Episode:
        episode = self.episodes[index]
        number, length = int(episode["episode_index"]), int(episode["length"])
        data_path, video_path, start = self._paths(episode)
        source = f"{data_path} (episode {number})"
        columns = ["episode_index", "timestamp", self.action_key]
        columns += [self.mask_key] if self.mask_key else []
        columns += [] if self.is_video else [self.camera]
        table = self._read_table(data_path, columns, source, filters=[("episode_index", "==", number)])
        if table.num_rows != length:
            raise EpisodeError(f"{source}: expected {length} rows (the episode's length), found {table.num_rows}")
        actions = _stack(table.column(self.action_key), source, self.action_key).astype(np.float32)
        timestamps = np.asarray(table.column("timestamp").to_numpy(), dtype=np.float64)
        if self.is_video:
            assert video_path is not None
            frames = self._decode_video(video_path, start + timestamps, f"{video_path} (episode {number})")
        else:
            frames = self._decode_images(table.column(self.camera).to_pylist(), source)
        masks = None
        if self.mask_key:
            masks = _resize_masks(_stack(table.column(self.mask_key), source, self.mask_key).astype(bool), frames)
        return make_episode(frames, actions, masks, source, self.min_frames)

    def _decode_video(self, path: str, times: np.ndarray, source: str) -> np.ndarray:
        """Frames (N, 3, H, W) at ``times`` (seconds): the decoded frame nearest each, within half a frame period."""
        av = self._av
        tolerance = 0.5 / self.fps
        decoded_times, images = [], []
        try:
            with av.open(path) as container:
                stream = container.streams.video[0]
                stream.thread_type = "AUTO"
                if times[0] > tolerance:
                    container.seek(int((times[0] - tolerance) / stream.time_base), stream=stream, backward=True)
                for frame in container.decode(stream):
                    if frame.time is None or frame.time < times[0] - tolerance:
                        continue
                    if frame.time > times[-1] + tolerance:
                        break
                    decoded_times.append(frame.time)
                    images.append(self._to_array(frame))
        except FileNotFoundError as error:
            raise EpisodeError(f"{source}: video file {path} is missing") from error
        except (av.error.FFmpegError, OSError, ValueError) as error:
            raise EpisodeError(f"{source}: cannot decode the video (damaged or truncated file?): {error}") from error
        decoded = np.asarray(decoded_times)
        if not len(decoded):
            raise EpisodeError(
                f"{source}: expected {len(times)} frames at {times[0]:.3f}-{times[-1]:.3f} s, found none "
                "(truncated or shorter video?)"
            )
        nearest = np.abs(decoded[None, :] - times[:, None]).argmin(axis=1)
        missing = np.abs(decoded[nearest] - times) > tolerance
        if missing.any():
            first = int(np.argmax(missing))
            raise EpisodeError(
                f"{source}: expected {len(times)} frames at {times[0]:.3f}-{times[-1]:.3f} s, found "
                f"{int((~missing).sum())}; frame {first} (t = {times[first]:.3f} s) is missing, the nearest decoded "
                f"frame is at {decoded[nearest[first]]:.3f} s (truncated video?)"
            )
        return np.stack([images[i] for i in nearest])

    def _to_array(self, frame: Any) -> np.ndarray:
        size = self.image_size
        kwargs = {"width": size, "height": size} if size else {}
        return frame.to_ndarray(format="rgb24", **kwargs).transpose(2, 0, 1)

    def _decode_images(self, values: list[Any], source: str) -> np.ndarray:
        images = []
        for step, value in enumerate(values):
            data: Any = value.get("bytes") if isinstance(value, dict) else value
            error = f"{source}: frame {step} of {self.camera!r} is not a PNG / JPEG image"
            images.append(decode_image(data, self.image_size, error))
        return np.stack(images)


def _stack(column: Any, source: str, name: str) -> np.ndarray:
    """A Parquet column of (nested) fixed-size lists or scalars -> (rows, ...) array."""
    rows = len(column)
    array = column.combine_chunks()
    shape = [rows]
    while hasattr(array, "flatten") and hasattr(array.type, "value_type"):
        flat = array.flatten()
        if len(array) and len(flat) % len(array):
            raise EpisodeError(f"{source}: column {name!r} holds rows of different lengths")
        shape.append(len(flat) // max(len(array), 1))
        array = flat
    values = array.to_numpy(zero_copy_only=False)
    if np.issubdtype(values.dtype, np.object_):
        raise EpisodeError(f"{source}: column {name!r} is not numeric ({array.type})")
    values = values.reshape(shape)
    return values[:, None] if values.ndim == 1 else values


def _resize_masks(masks: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Nearest-neighbour resize of (N, h, w) masks to the frames' size."""
    height, width = frames.shape[2:]
    if masks.ndim == 3 and masks.shape[1:] != (height, width):
        rows = np.arange(height) * masks.shape[1] // height
        cols = np.arange(width) * masks.shape[2] // width
        masks = masks[:, rows][:, :, cols]
    return masks
