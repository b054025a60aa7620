"""LeRobot datasets (Parquet tables + MP4 videos) read and written with pyarrow and PyAV, without the ``lerobot``
package (which pulls in torchvision, datasets, huggingface-hub and its own video stack).

Layout of a v3.0 dataset folder (several episodes per file)::

    meta/info.json                                  codebase_version, fps, features, data_path / video_path templates
    meta/episodes/chunk-000/file-000.parquet        one row per episode: episode_index, length, data/chunk_index,
                                                    data/file_index, videos/<camera>/{chunk_index, file_index,
                                                    from_timestamp, to_timestamp}, ...
    data/chunk-000/file-000.parquet                 one row per frame: action, timestamp, frame_index, episode_index
    videos/<camera>/chunk-000/file-000.mp4          the camera's frames of consecutive episodes, one after another

Frame ``i`` of an episode is the video frame at ``from_timestamp + timestamp[i]``. v2.x folders (one Parquet file and
one MP4 per episode, ``meta/episodes.jsonl``, paths from ``{episode_chunk}`` / ``{episode_index}``) are read too.
Row ``i`` pairs frame ``i`` with action ``i``: the last action has no frame after it and is dropped
(:func:`~sb3_ef.offline.episodes.make_episode`).
"""

from __future__ import annotations

import glob
import io
import json
import os
from collections.abc import Iterable
from fractions import Fraction
from typing import Any

import numpy as np

from sb3_ef.offline.episodes import Episode, EpisodeError, make_episode
from sb3_ef.offline.readers import EpisodeDataset

INFO = os.path.join("meta", "info.json")
V3_DATA_PATH = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
V3_VIDEO_PATH = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
V3_EPISODES_PATH = "meta/episodes/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
VIDEO_COLUMNS = ("chunk_index", "file_index", "from_timestamp", "to_timestamp")
#: The Parquet column of the agent masks written by :class:`LeRobotWriter` (not a LeRobot convention).
MASK_KEY = "observation.agent_mask"


def is_lerobot_dataset(path: str | os.PathLike) -> bool:
    return os.path.isfile(os.path.join(os.fspath(path), INFO))


def _imports() -> tuple[Any, Any]:
    try:
        import av
        import pyarrow.parquet as pq
    except ImportError as error:
        raise ImportError("LeRobot datasets need pyarrow and av (PyAV): pip install sb3-ef[offline]") from error
    return av, pq


class LeRobotDataset(EpisodeDataset):
    """Episodes of a local LeRobot dataset folder (v3.0, or v2.x): one camera's frames and the actions.

    Episodes are indexed on open from the metadata (no frame is decoded); ``dataset[i]`` reads episode ``i``'s rows
    from its Parquet file and decodes its frames from the camera's MP4 (seeking to the episode's first frame).
    Cameras stored as ``video`` (MP4: any codec of the installed FFmpeg, AV1 and H.264 included) or ``image``
    (PNG / JPEG bytes in the Parquet table) are read.

    :param root: the dataset folder (holding ``meta/info.json``).
    :param camera: the camera feature, e.g. ``"observation.images.top"`` (default: the first video or image
        feature of ``meta/info.json``).
    :param action_key: the action feature (a float vector per frame).
    :param image_size: resize frames to ``image_size`` x ``image_size`` (None: keep the camera's size); the
        aspect ratio is not kept.
    :param mask_key: a per-frame boolean (height, width) feature with agent masks (default: ``MASK_KEY`` when the
        dataset has it).
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
        self._av, self._pq = _imports()
        self.root = os.fspath(root)
        info_path = os.path.join(self.root, INFO)
        if not os.path.isfile(info_path):
            raise FileNotFoundError(f"{self.root!r} is not a LeRobot dataset: no {INFO}")
        try:
            with open(info_path) as file:
                self.info = json.load(file)
        except json.JSONDecodeError as error:
            raise EpisodeError(f"{info_path}: not valid JSON ({error})") from error
        self.version = str(self.info.get("codebase_version", ""))
        if not self.version.startswith(("v2", "v3")):
            raise EpisodeError(f"{info_path}: expected codebase_version v2.x or v3.x, got {self.version!r}")
        required = ("fps", "features") + (("data_path",) if self.version.startswith("v2") else ())
        missing = [key for key in required if key not in self.info]
        if missing:
            raise EpisodeError(f"{info_path}: missing {missing} (a LeRobot {self.version} info.json has them)")
        features = self.info.get("features", {})
        cameras = [key for key, feature in features.items() if feature.get("dtype") in ("video", "image")]
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
        self.image_size = image_size
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
            rows = []
            for path in paths:
                # only the columns used here: real episode tables also hold per-episode statistics of every feature
                wanted = ["episode_index", "length", "data/chunk_index", "data/file_index"]
                wanted += [f"videos/{self.camera}/{key}" for key in VIDEO_COLUMNS] if self.is_video else []
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

    def __getitem__(self, index: int) -> Episode:
        self._check_index(index)
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
        from PIL import Image

        images = []
        for step, value in enumerate(values):
            data: Any = value.get("bytes") if isinstance(value, dict) else value
            try:
                image = Image.open(io.BytesIO(data)).convert("RGB")
            except Exception as error:
                raise EpisodeError(f"{source}: frame {step} of {self.camera!r} is not a PNG / JPEG image") from error
            if self.image_size:
                image = image.resize((self.image_size, self.image_size), Image.Resampling.BILINEAR)
            images.append(np.asarray(image).transpose(2, 0, 1))
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


class LeRobotWriter:
    """Writes episodes as a LeRobot v3.0 dataset folder: one camera (MP4), the actions and optionally agent masks.

    Row ``t`` of an episode holds frame ``t`` and action ``t``; the last frame has no action and gets zeros (the
    reader drops it again). Timestamps are ``frame_index / fps``.

    :param codec: an FFmpeg video encoder: ``"libsvtav1"`` (AV1, LeRobot's default; lossy), ``"libx264"`` (H.264,
        lossy) or ``"libx264rgb"`` (H.264 in RGB with ``qp=0``: lossless, frames read back exactly).
    :param episodes_per_file: start a new data and video file every this many episodes (None: one file each).
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
    ):
        self._av, self._pq = _imports()
        import pyarrow as pa

        self._pa = pa
        self.root = os.fspath(root)
        if os.path.exists(os.path.join(self.root, INFO)):
            raise FileExistsError(f"{self.root} already holds a LeRobot dataset ({INFO}); write to another folder")
        channels, height, width = frame_shape
        if channels != 3 or height % 2 or width % 2:
            raise ValueError(f"Expected RGB frames (3, H, W) with even H and W for video, got {frame_shape}")
        self.frame_shape, self.action_dim, self.fps = tuple(frame_shape), action_dim, fps
        self.camera, self.codec, self.with_masks, self.task = camera, codec, masks, task
        self.episodes_per_file, self.crf = episodes_per_file, crf
        self.robot_type = robot_type
        self._rows: list[dict[str, Any]] = []  # episode table
        self._file_index, self._in_file, self._frames, self._file_frames = 0, 0, 0, 0
        self._data_writer: Any = None
        self._container: Any = None
        self._stream: Any = None

    def add(self, episode: Episode) -> None:
        """Append one episode (its frames, actions and, when the writer records masks, masks)."""
        if episode.frame_shape != self.frame_shape or episode.action_dim != self.action_dim:
            raise ValueError(
                f"{episode.source}: frames {episode.frame_shape} and {episode.action_dim}-d actions differ from the "
                f"dataset's {self.frame_shape} and {self.action_dim}-d actions"
            )
        if self.with_masks and episode.masks is None:
            raise ValueError(f"{episode.source}: the dataset records agent masks and this episode has none")
        if self.episodes_per_file and self._in_file == self.episodes_per_file:
            self._close_files()
            self._file_index += 1
        if self._container is None:
            self._open_files()
        length = len(episode.frames)
        start_time = self._file_frames / self.fps
        for frame in episode.frames:
            video_frame = self._av.VideoFrame.from_ndarray(np.ascontiguousarray(frame.transpose(1, 2, 0)), "rgb24")
            video_frame.pts, video_frame.time_base = self._file_frames, Fraction(1, self.fps)
            for packet in self._stream.encode(video_frame):
                self._container.mux(packet)
            self._file_frames += 1
        self._write_rows(episode, len(self._rows))
        location = {"chunk_index": 0, "file_index": self._file_index}
        self._rows.append(
            {
                "episode_index": len(self._rows),
                "tasks": [self.task],
                "length": length,
                **{f"data/{key}": value for key, value in location.items()},
                "dataset_from_index": self._frames,
                "dataset_to_index": self._frames + length,
                **{f"videos/{self.camera}/{key}": value for key, value in location.items()},
                f"videos/{self.camera}/from_timestamp": start_time,
                f"videos/{self.camera}/to_timestamp": self._file_frames / self.fps,
                "meta/episodes/chunk_index": 0,
                "meta/episodes/file_index": 0,
            }
        )
        self._frames += length
        self._in_file += 1

    def extend(self, episodes: Iterable[Episode]) -> LeRobotWriter:
        for episode in episodes:
            self.add(episode)
        return self

    def _open_files(self) -> None:
        location = {"video_key": self.camera, "chunk_index": 0, "file_index": self._file_index}
        video = os.path.join(self.root, V3_VIDEO_PATH.format(**location))
        os.makedirs(os.path.dirname(video), exist_ok=True)
        lossless = self.codec == "libx264rgb"
        os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration per file unless told errors only
        options = {"qp": "0"} if lossless else {"crf": str(self.crf)}
        self._container = self._av.open(video, "w")
        self._stream = self._container.add_stream(self.codec, rate=self.fps, options=options)
        self._stream.height, self._stream.width = self.frame_shape[1:]
        self._stream.pix_fmt = "rgb24" if lossless else "yuv420p"
        self._stream.codec_context.gop_size = 2  # LeRobot's keyframe interval: cheap seeks to any episode
        self._file_frames, self._in_file = 0, 0

    def _write_rows(self, episode: Episode, index: int) -> None:
        pa = self._pa
        length = len(episode.frames)
        actions = np.zeros((length, self.action_dim), np.float32)
        actions[: episode.steps] = episode.actions
        columns = {
            "action": pa.FixedSizeListArray.from_arrays(pa.array(actions.ravel()), self.action_dim),
            "timestamp": pa.array(np.arange(length, dtype=np.float32) / self.fps),
            "frame_index": pa.array(np.arange(length, dtype=np.int64)),
            "episode_index": pa.array(np.full(length, index, dtype=np.int64)),
            "index": pa.array(np.arange(self._frames, self._frames + length, dtype=np.int64)),
            "task_index": pa.array(np.zeros(length, dtype=np.int64)),
        }
        if self.with_masks:
            height, width = self.frame_shape[1:]
            rows = pa.FixedSizeListArray.from_arrays(pa.array(episode.masks.ravel()), width)  # type: ignore[union-attr]
            columns[MASK_KEY] = pa.FixedSizeListArray.from_arrays(rows, height)
        table = pa.table(columns)
        if self._data_writer is None:
            path = os.path.join(self.root, V3_DATA_PATH.format(chunk_index=0, file_index=self._file_index))
            os.makedirs(os.path.dirname(path), exist_ok=True)
            self._data_writer = self._pq.ParquetWriter(path, table.schema, compression="snappy")
        self._data_writer.write_table(table)  # one row group per episode

    def _close_files(self) -> None:
        if self._container is not None:
            for packet in self._stream.encode():
                self._container.mux(packet)
            self._container.close()
            self._container = None
        if self._data_writer is not None:
            self._data_writer.close()
            self._data_writer = None

    def close(self) -> str:
        """Finish the files and write the episode table and ``meta/info.json``; returns the dataset folder."""
        self._close_files()
        pa = self._pa
        if not self._rows:
            raise ValueError(f"No episode was added to {self.root}")
        table = pa.Table.from_pylist(self._rows)
        path = os.path.join(self.root, V3_EPISODES_PATH.format(chunk_index=0, file_index=0))
        os.makedirs(os.path.dirname(path), exist_ok=True)
        self._pq.write_table(table, path)
        self._pq.write_table(
            pa.table({"task_index": [0], "task": [self.task]}), os.path.join(self.root, "meta", "tasks.parquet")
        )
        height, width = self.frame_shape[1:]
        codec_name = {"libsvtav1": "av1", "libx264": "h264", "libx264rgb": "h264"}.get(self.codec, self.codec)
        features: dict[str, Any] = {
            self.camera: {
                "dtype": "video",
                "shape": [height, width, 3],
                "names": ["height", "width", "channels"],
                "info": {
                    "video.height": height,
                    "video.width": width,
                    "video.codec": codec_name,
                    "video.pix_fmt": "rgb24" if self.codec == "libx264rgb" else "yuv420p",
                    "video.is_depth_map": False,
                    "video.fps": self.fps,
                    "video.channels": 3,
                    "has_audio": False,
                },
            },
            "action": {"dtype": "float32", "shape": [self.action_dim], "names": None},
        }
        if self.with_masks:
            features[MASK_KEY] = {"dtype": "bool", "shape": [height, width], "names": ["height", "width"]}
        for name, dtype in (
            ("timestamp", "float32"),
            ("frame_index", "int64"),
            ("episode_index", "int64"),
            ("index", "int64"),
            ("task_index", "int64"),
        ):
            features[name] = {"dtype": dtype, "shape": [1], "names": None}
        info = {
            "codebase_version": "v3.0",
            "robot_type": self.robot_type,
            "total_episodes": len(self._rows),
            "total_frames": self._frames,
            "total_tasks": 1,
            "chunks_size": 1000,
            "data_files_size_in_mb": 100,
            "video_files_size_in_mb": 200,
            "fps": self.fps,
            "splits": {"train": f"0:{len(self._rows)}"},
            "data_path": V3_DATA_PATH,
            "video_path": V3_VIDEO_PATH,
            "features": features,
        }
        with open(os.path.join(self.root, INFO), "w") as file:
            json.dump(info, file, indent=4)
        return self.root

    def __enter__(self) -> LeRobotWriter:
        return self

    def __exit__(self, *exc_info: Any) -> None:
        if exc_info[0] is None:
            self.close()
        else:
            self._close_files()


def write_lerobot(root: str | os.PathLike, episodes: list[Episode], **kwargs: Any) -> str:
    """Write ``episodes`` as a LeRobot v3.0 dataset (see :class:`LeRobotWriter` for the options)."""
    if not episodes:
        raise ValueError("No episodes to write")
    first = episodes[0]
    kwargs.setdefault("masks", all(episode.masks is not None for episode in episodes))
    with LeRobotWriter(root, first.frame_shape, first.action_dim, **kwargs) as writer:
        writer.extend(episodes)
    return os.fspath(root)
