"""Readers of (frames, actions) episodes behind one interface: a folder of NPZ / HDF5 files, a Minari dataset, and
BAIR's robot-pushing TFRecords (``softmotion30_44k``), all yielding :class:`~sb3_ef.offline.episodes.Episode`.

``open_dataset`` picks the reader from the source: ``minari:<dataset id>``, a LeRobot dataset folder
(:mod:`sb3_ef.offline.lerobot`), an RLDS / TFDS folder or ``rlds:<path>`` (:mod:`sb3_ef.offline.rlds`), a
``.tfrecord`` file or a folder of them (BAIR), or a folder of ``.npz`` / ``.h5`` episodes.
"""

from __future__ import annotations

import glob
import io
import os
import zipfile
import zlib
from abc import ABC, abstractmethod
from collections.abc import Iterator, Sequence

import numpy as np

from sb3_ef.offline.episodes import HDF5_SUFFIXES, NPZ_SUFFIXES, Episode, EpisodeError, make_episode
from sb3_ef.offline.tfrecord import Features, parse_example, read_record_at, record_offsets

TFRECORD_SUFFIXES = (".tfrecord", ".tfrecords")
MINARI_PREFIX = "minari:"
RLDS_PREFIX = "rlds:"


class EpisodeDataset(ABC):
    """A sequence of episodes: ``len(dataset)``, ``dataset[i]`` and iteration, each read on demand.

    :param min_frames: the fewest frames an episode may have (context + horizon); shorter ones raise.
    """

    def __init__(self, min_frames: int = 2):
        self.min_frames = min_frames

    @abstractmethod
    def __len__(self) -> int: ...

    @abstractmethod
    def __getitem__(self, index: int) -> Episode: ...

    def __iter__(self) -> Iterator[Episode]:
        for index in range(len(self)):
            yield self[index]

    def lengths(self) -> list[int]:
        """Frames per episode, to index the dataset for streaming. Readers that know them from metadata or headers
        override this; here every episode is read once (and let go)."""
        return [len(episode.frames) for episode in self]

    def _check_index(self, index: int) -> None:
        if not 0 <= index < len(self):
            raise IndexError(f"Episode index {index} out of range for a dataset of {len(self)} episodes")


class FolderDataset(EpisodeDataset):
    """One episode per ``.npz`` / ``.h5`` / ``.hdf5`` file of a folder (sorted by name) with the arrays ``frames``
    (uint8 (T + 1, 3, H, W)), ``actions`` ((T, action_dim)) and optionally ``masks`` (bool (T + 1, H, W))."""

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
        """Frames per episode from the array headers (no frame is decompressed)."""
        return [_frame_count(path, f"{path} (episode {index})") for index, path in enumerate(self.paths)]

    def __getitem__(self, index: int) -> Episode:
        self._check_index(index)
        path = self.paths[index]
        source = f"{path} (episode {index})"
        if path.endswith(NPZ_SUFFIXES):
            arrays = _read_npz(path, source)
        else:
            import h5py

            try:
                with h5py.File(path, "r") as file:
                    arrays = {key: file[key][()] for key in file}
            except OSError as error:
                raise EpisodeError(f"{source}: not a readable HDF5 file ({error})") from error
        missing = [key for key in ("frames", "actions") if key not in arrays]
        if missing:
            raise EpisodeError(f"{source}: missing {missing}; expected keys 'frames', 'actions' and optionally 'masks'")
        return make_episode(arrays["frames"], arrays["actions"], arrays.get("masks"), source, self.min_frames)


def _read_npz(path: str, source: str) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` episode; a damaged file or one holding Python objects is an ``EpisodeError``."""
    try:
        with np.load(path, allow_pickle=False) as file:
            return {key: file[key] for key in file.files}
    except ValueError as error:  # numpy: object arrays, or not an npz at all
        raise EpisodeError(f"{source}: not a readable .npz of numeric arrays (corrupt, or holds objects)") from error
    except (OSError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        raise EpisodeError(f"{source}: corrupt or truncated .npz file ({error})") from error


def _frame_count(path: str, source: str) -> int:
    """Frames of an episode file from the header of its ``frames`` array."""
    try:
        if path.endswith(NPZ_SUFFIXES):
            with zipfile.ZipFile(path) as archive, archive.open("frames.npy") as member:
                major, _ = np.lib.format.read_magic(member)
                read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
                shape = read_header(member)[0]
        else:
            import h5py

            with h5py.File(path, "r") as file:
                shape = file["frames"].shape
    except KeyError as error:
        raise EpisodeError(f"{source}: missing ['frames']; expected keys 'frames', 'actions'") from error
    except (OSError, ValueError, zipfile.BadZipFile, zlib.error) as error:
        raise EpisodeError(f"{source}: corrupt or truncated episode file ({error})") from error
    return int(shape[0])


class MinariDataset(EpisodeDataset):
    """Episodes of a local Minari dataset whose observations are images (or a dict holding one).

    Images may be channels-last (T + 1, H, W, 3), Minari's and Gymnasium's usual layout, or channels-first
    (T + 1, 3, H, W), or frame-stacked channels-first (T + 1, 3 * k, H, W) as sb3-ef envs emit (the newest frame
    is kept). Agent masks are read from the step infos under ``mask_key`` when present.

    :param dataset_id: the Minari id, e.g. ``"metaworld/hammer/babbling-v0"``.
    :param observation_key: the image entry of dict observations (default: ``"pixels"`` or ``"image"``).
    """

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

    def __getitem__(self, index: int) -> Episode:
        self._check_index(index)
        (data,) = self._dataset.iterate_episodes([self._ids[index]])
        source = f"minari:{self.dataset_id} (episode {self._ids[index]})"
        observations = data.observations
        if isinstance(observations, dict):
            key = self.observation_key or next((k for k in ("pixels", "image") if k in observations), None)
            if key not in observations:
                raise EpisodeError(f"{source}: no image entry {key!r} in observations {sorted(observations)}")
            observations = observations[key]
        frames = _channels_first(_decode_encoded_frames(observations), source)
        infos = data.infos if isinstance(data.infos, dict) else {}
        return make_episode(frames, data.actions, infos.get(self.mask_key), source, self.min_frames)


def _decode_encoded_frames(observations) -> np.ndarray:
    """Minari's HDF5 storage keeps image observations as JPEG bytes and may hand them back undecoded."""
    observations = np.asarray(observations) if not isinstance(observations, np.ndarray) else observations
    if observations.dtype != object:
        return observations
    from PIL import Image

    return np.stack([np.asarray(Image.open(io.BytesIO(bytes(frame))).convert("RGB")) for frame in observations])


def _channels_first(images: np.ndarray, source: str) -> np.ndarray:
    """(N, H, W, 3) or (N, 3 * k, H, W) -> (N, 3, H, W) (the newest of k stacked frames)."""
    if images.ndim == 4 and images.shape[-1] == 3 and images.shape[1] != 3:
        return images.transpose(0, 3, 1, 2)
    if images.ndim == 4 and images.shape[1] % 3 == 0:
        return images[:, -3:]
    raise EpisodeError(
        f"{source}: expected image observations (T + 1, H, W, 3) or (T + 1, 3 * k, H, W), got {images.shape}"
    )


class BAIRDataset(EpisodeDataset):
    """BAIR robot pushing (``softmotion30_44k``) TFRecords: one ``tf.train.Example`` per episode, per step ``t`` the
    features ``{t}/{camera}/encoded`` (the frame: raw RGB bytes of ``image_size`` x ``image_size``, as published,
    or a JPEG / PNG), ``{t}/action`` (4 floats) and ``{t}/endeffector_pos`` (3 floats, kept out of the episode).

    The published files hold 30 frames and 30 actions per episode; the last action is dropped (no frame follows it).
    Read without TensorFlow (:mod:`sb3_ef.offline.tfrecord`).

    :param paths: TFRecord files, or one folder searched for ``*.tfrecord(s)``.
    :param camera: ``"image_aux1"`` (the 64x64 view used for video prediction) or ``"image_main"``.
    :param verify: check each record's CRC-32C when it is read (in C when ``google-crc32c`` or ``crc32c`` is
        installed: a small cost next to decoding).
    """

    def __init__(
        self,
        paths: str | os.PathLike | Sequence[str | os.PathLike],
        camera: str = "image_aux1",
        image_size: int = 64,
        min_frames: int = 2,
        verify: bool = True,
    ):
        super().__init__(min_frames)
        self.verify = verify
        if isinstance(paths, (str, os.PathLike)) and os.path.isdir(paths):
            paths = sorted(p for p in glob.glob(os.path.join(paths, "*")) if p.endswith(TFRECORD_SUFFIXES))
        self.paths = [os.fspath(path) for path in ([paths] if isinstance(paths, (str, os.PathLike)) else paths)]
        if not self.paths:
            raise FileNotFoundError("No .tfrecord files given or found")
        self.camera = camera
        self.image_size = image_size
        self._offsets = [(path, offset) for path in self.paths for offset in _offsets(path)]

    def __len__(self) -> int:
        return len(self._offsets)

    def lengths(self) -> list[int]:
        """Frames per episode from each record's step features (records are parsed, images not decoded)."""
        return [len(self._steps(index)[1]) for index in range(len(self))]

    def _steps(self, index: int) -> tuple[Features, list[int], str]:
        path, offset = self._offsets[index]
        source = f"{path} (episode {index})"
        features = parse_record(_read_record(path, offset, source, self.verify), source)
        steps = sorted({int(key.split("/", 1)[0]) for key in features if key.split("/", 1)[0].isdigit()})
        return features, steps, source

    def __getitem__(self, index: int) -> Episode:
        self._check_index(index)
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
            image = np.frombuffer(data, dtype=np.uint8).reshape(size, size, 3)
        else:
            from PIL import Image

            try:
                image = np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))
            except Exception as error:
                raise EpisodeError(
                    f"{source}: image is neither {size}x{size}x3 raw bytes nor a JPEG/PNG ({len(data)} bytes)"
                ) from error
        return image.transpose(2, 0, 1)


def _offsets(path: str) -> list[int]:
    try:
        return record_offsets(path)
    except ValueError as error:
        raise EpisodeError(str(error)) from error


def _read_record(path: str, offset: int, source: str, verify: bool) -> bytes:
    """One TFRecord record read at random, its CRCs checked when ``verify``; errors name ``source``."""
    with open(path, "rb") as file:
        try:
            return read_record_at(file, offset, path, verify)
        except ValueError as error:
            raise EpisodeError(f"{source}: {error}") from error


def parse_record(data: bytes, source: str) -> Features:
    """``parse_example`` whose errors name ``source``."""
    try:
        return parse_example(data)
    except ValueError as error:
        raise EpisodeError(f"{source}: {error}") from error


def open_dataset(source: str | os.PathLike, min_frames: int = 2, **kwargs) -> EpisodeDataset:
    """The reader for ``source``: ``minari:<id>``, a LeRobot folder, an RLDS folder (or ``rlds:<path>``),
    ``.tfrecord`` file(s) / a folder of them (BAIR), or a folder of episodes; ``kwargs`` go to the reader."""
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
    """Read every episode of ``dataset`` into memory, checked; the episodes must share frame shape and action size."""
    episodes = list(dataset)
    if not episodes:
        raise EpisodeError("The dataset holds no episodes")
    first = episodes[0]
    for episode in episodes[1:]:
        if episode.frame_shape != first.frame_shape or episode.action_dim != first.action_dim:
            raise EpisodeError(
                f"{episode.source}: frames {episode.frame_shape} and {episode.action_dim}-d actions differ from "
                f"{first.source}: frames {first.frame_shape} and {first.action_dim}-d actions"
            )
    return episodes
