"""Episode readers of NPZ / HDF5 folders, Minari and BAIR's TFRecords, and ``open_dataset``, which picks a reader."""

from __future__ import annotations

import glob
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from sb3_ef.offline.dataset import EpisodeDataset, check_image_size, check_like, decode_image
from sb3_ef.offline.episodes import (
    HDF5_SUFFIXES,
    NPZ_SUFFIXES,
    Episode,
    EpisodeError,
    episode_file_shapes,
    make_episode,
    read_episode_file,
)
from sb3_ef.offline.tfrecord import ExampleShards, Features

TFRECORD_SUFFIXES = (".tfrecord", ".tfrecords")
MINARI_PREFIX = "minari:"
RLDS_PREFIX = "rlds:"


class FolderDataset(EpisodeDataset):
    """One episode per ``.npz`` / ``.h5`` / ``.hdf5`` file of a folder, sorted by name."""

    def __init__(self, directory: str | os.PathLike, min_frames: int = 2):
        super().__init__(min_frames)
        self.directory = os.fspath(directory)
        if not os.path.isdir(self.directory):
            raise FileNotFoundError(f"Episode folder {self.directory!r} does not exist")
        self.paths = sorted(
            path for path in glob.glob(os.path.join(self.directory, "*")) if path.endswith(NPZ_SUFFIXES + HDF5_SUFFIXES)
        )
        if not self.paths:
            raise FileNotFoundError(f"No .npz, .h5 or .hdf5 episode files in {self.directory!r}")

    def __len__(self) -> int:
        return len(self.paths)

    def lengths(self) -> list[int]:
        """Frames per episode from the array headers, whose shapes must agree."""
        lengths, first = [], None
        for index, path in enumerate(self.paths):
            source = f"{path} (episode {index})"
            frames, actions = episode_file_shapes(path, source)
            shapes = (frames[1:], actions[1:])
            if first is None:
                first = (shapes, source)
            elif shapes != first[0]:
                raise EpisodeError(
                    f"{source}: frames of shape {frames[1:]} and actions of shape {actions[1:]} differ from "
                    f"{first[1]}: {first[0][0]} and {first[0][1]} (the episodes of a dataset share one frame shape and "
                    "action size)"
                )
            lengths.append(int(frames[0]))
        return lengths

    def _read(self, index: int) -> Episode:
        path = self.paths[index]
        return read_episode_file(path, f"{path} (episode {index})", self.min_frames)


class MinariDataset(EpisodeDataset):
    """Episodes of a local Minari dataset of image observations; agent masks from infos' ``mask_key``."""

    def __init__(
        self, dataset_id: str, observation_key: str | None = None, mask_key: str = "agent_mask", min_frames: int = 2
    ):
        super().__init__(min_frames)
        try:
            import minari
        except ImportError as error:
            raise ImportError("Reading Minari datasets needs minari: pip install sb3-ef[offline]") from error
        self.dataset_id = dataset_id
        self.observation_key = observation_key
        self.mask_key = mask_key
        self._dataset = minari.load_dataset(dataset_id)
        self._ids = list(self._dataset.episode_indices)

    def __len__(self) -> int:
        return len(self._ids)

    def _read(self, index: int) -> Episode:
        (data,) = self._dataset.iterate_episodes([self._ids[index]])
        source = f"minari:{self.dataset_id} (episode {self._ids[index]})"
        observations = data.observations
        if isinstance(observations, dict):
            key = self.observation_key or next((k for k in ("pixels", "image") if k in observations), None)
            if key not in observations:
                raise EpisodeError(f"{source}: no image entry {key!r} in observations {sorted(observations)}")
            observations = observations[key]
        frames = _channels_first(_decode_encoded_frames(observations, source), source)
        infos = data.infos if isinstance(data.infos, dict) else {}
        return make_episode(frames, data.actions, infos.get(self.mask_key), source, self.min_frames)


def _decode_encoded_frames(observations: Any, source: str) -> np.ndarray:
    """Minari's HDF5 storage keeps image observations as JPEG bytes and may hand them back undecoded."""
    observations = np.asarray(observations)
    if observations.dtype != object:
        return observations
    error = f"{source}: an observation is neither an image array nor a JPEG / PNG"
    return np.stack([decode_image(bytes(frame), None, error) for frame in observations])


def _channels_first(images: np.ndarray, source: str) -> np.ndarray:
    """(N, H, W, 3) or (N, 3 * k, H, W) -> (N, 3, H, W) (the newest of k stacked frames)."""
    if images.ndim == 4 and images.shape[-1] == 3 and images.shape[1] != 3:
        return images.transpose(0, 3, 1, 2)
    if images.ndim == 4 and images.shape[1] % 3 == 0:
        return images[:, -3:]
    raise EpisodeError(
        f"{source}: expected image observations (T + 1, H, W, 3) or (T + 1, 3 * k, H, W), got {images.shape}"
    )


class BAIRDataset(ExampleShards):
    """BAIR robot pushing (``softmotion30_44k``) TFRecords; ``camera``: ``"image_aux1"`` (64x64) or ``"image_main"``."""

    def __init__(
        self,
        paths: str | os.PathLike | Sequence[str | os.PathLike],
        camera: str = "image_aux1",
        image_size: int = 64,
        min_frames: int = 2,
        verify: bool = True,
    ):
        if isinstance(paths, (str, os.PathLike)) and os.path.isdir(paths):
            paths = sorted(p for p in glob.glob(os.path.join(paths, "*")) if p.endswith(TFRECORD_SUFFIXES))
        shards = [os.fspath(path) for path in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
        if not shards:
            raise FileNotFoundError("No .tfrecord files given or found")
        self.camera = camera
        self.image_size = check_image_size(image_size, optional=False)
        super().__init__(shards, verify, min_frames)

    def lengths(self) -> list[int]:
        """Frames per episode from each record's step features (records are parsed, images not decoded)."""
        return [len(self._steps(index)[1]) for index in range(len(self))]

    def _steps(self, index: int) -> tuple[Features, list[int], str]:
        features, source = self._example(index)
        steps = sorted({int(key.split("/", 1)[0]) for key in features if key.split("/", 1)[0].isdigit()})
        return features, steps, source

    def _read(self, index: int) -> Episode:
        features, steps, source = self._steps(index)
        if not steps:
            raise EpisodeError(f"{source}: no per-step features '{{t}}/{self.camera}/encoded' in this record")
        frames, actions = [], []
        for step in range(steps[-1] + 1):
            image_key, action_key = f"{step}/{self.camera}/encoded", f"{step}/action"
            for key in (image_key, action_key):
                if key not in features:
                    raise EpisodeError(f"{source}: missing feature {key!r} (steps 0..{steps[-1]} expected)")
            frames.append(self._decode_image(features[image_key], f"{source} step {step}"))
            actions.append(np.asarray(features[action_key], dtype=np.float32))
        if len({action.shape for action in actions}) != 1:
            raise EpisodeError(f"{source}: actions differ in size across steps: {sorted({a.size for a in actions})}")
        return make_episode(np.stack(frames), np.stack(actions), None, source, self.min_frames)

    def _decode_image(self, value: list[bytes] | np.ndarray, source: str) -> np.ndarray:
        if not isinstance(value, list) or len(value) != 1:
            raise EpisodeError(f"{source}: expected one bytes value for the image, got {type(value).__name__}")
        data = value[0]
        size = self.image_size
        if len(data) == size * size * 3:
            return np.frombuffer(data, dtype=np.uint8).reshape(size, size, 3).transpose(2, 0, 1)
        error = f"{source}: image is neither {size}x{size}x3 raw bytes nor a JPEG/PNG ({len(data)} bytes)"
        return decode_image(data, None, error)


def open_dataset(source: str | os.PathLike, min_frames: int = 2, **kwargs) -> EpisodeDataset:
    """The reader for ``source`` (see docs/offline.md's Readers); ``kwargs`` go to the reader."""
    from sb3_ef.offline.lerobot import LeRobotDataset, is_lerobot_dataset
    from sb3_ef.offline.rlds import RLDSDataset, is_rlds_folder

    text = os.fspath(source)
    if text.startswith(MINARI_PREFIX):
        return MinariDataset(text[len(MINARI_PREFIX) :], min_frames=min_frames, **kwargs)
    if text.startswith(RLDS_PREFIX) or is_rlds_folder(text):
        return RLDSDataset(text.removeprefix(RLDS_PREFIX), min_frames=min_frames, **kwargs)
    if is_lerobot_dataset(text):
        return LeRobotDataset(text, min_frames=min_frames, **kwargs)
    if text.endswith(TFRECORD_SUFFIXES) or (
        os.path.isdir(text) and any(p.endswith(TFRECORD_SUFFIXES) for p in os.listdir(text))
    ):
        return BAIRDataset(text, min_frames=min_frames, **kwargs)
    if kwargs:
        raise TypeError(f"Options {sorted(kwargs)} do not apply to a folder of .npz / .h5 episodes ({text})")
    return FolderDataset(text, min_frames=min_frames)


def load_episodes(dataset: EpisodeDataset) -> list[Episode]:
    """Every episode of ``dataset`` in memory, checked to share one frame shape and action size."""
    episodes = list(dataset)
    if not episodes:
        raise EpisodeError("The dataset holds no episodes")
    return [check_like(episode, episodes[0]) for episode in episodes]
