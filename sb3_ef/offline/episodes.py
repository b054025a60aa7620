"""One episode of robot video with actions (the contract in docs/offline.md), its checks, and the folder format."""

from __future__ import annotations

import os
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.files import atomic_path

NPZ_SUFFIXES = (".npz",)
HDF5_SUFFIXES = (".h5", ".hdf5")


class EpisodeError(ValueError):
    """Bad episode data; the message names the file, the episode and what was expected."""


@dataclass(frozen=True)
class Episode:
    """Frames, actions and (optionally) agent masks of one episode; see the module docstring for the shapes."""

    frames: np.ndarray
    actions: np.ndarray
    masks: np.ndarray | None = None
    source: str = ""

    @property
    def steps(self) -> int:
        """T, the number of actions."""
        return len(self.actions)

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        return tuple(self.frames.shape[1:])

    @property
    def action_dim(self) -> int:
        return self.actions.shape[1]


def make_episode(
    frames: np.ndarray, actions: np.ndarray, masks: np.ndarray | None = None, source: str = "", min_frames: int = 2
) -> Episode:
    """Check one episode's arrays (``EpisodeError`` naming ``source``) and return it as an :class:`Episode`."""
    frames, actions = np.asarray(frames), np.asarray(actions)
    if frames.dtype != np.uint8:
        raise EpisodeError(f"{source}: expected uint8 frames (0-255), got dtype {frames.dtype}")
    if frames.ndim != 4 or frames.shape[1] != FRAME_CHANNELS:
        raise EpisodeError(f"{source}: expected frames of shape (T + 1, 3, height, width), got {frames.shape}")
    if actions.ndim != 2 or not np.issubdtype(actions.dtype, np.number):
        raise EpisodeError(f"{source}: expected numeric actions of shape (T, action_dim), got {actions.shape}")
    if len(frames) == len(actions):
        actions = actions[:-1]  # T frames for T actions: the last action has no frame after it
    if len(frames) != len(actions) + 1:
        raise EpisodeError(
            f"{source}: expected T + 1 (or T) frames for T actions, got {len(frames)} frames and {len(actions)} actions"
        )
    check_length(len(frames), min_frames, source)
    if masks is not None:
        masks = np.asarray(masks)
        if masks.dtype != bool and not np.isin(masks, (0, 1)).all():
            raise EpisodeError(f"{source}: expected boolean (or 0/1) agent masks, got dtype {masks.dtype}")
        if masks.shape != (len(frames), *frames.shape[2:]):
            raise EpisodeError(
                f"{source}: expected agent masks of shape {(len(frames), *frames.shape[2:])}, got {masks.shape}"
            )
        masks = masks.astype(bool)
    return Episode(np.ascontiguousarray(frames), actions.astype(np.float32), masks, source)


def check_length(frames: int, min_frames: int, source: str) -> None:
    if frames < min_frames:
        raise EpisodeError(
            f"{source}: episode of {frames} frames is shorter than context + horizon = {min_frames} frames"
        )


def write_episode(path: str | os.PathLike, episode: Episode) -> str:
    """Write one episode as ``.npz`` (compressed) or ``.h5`` / ``.hdf5`` by suffix, whole or not at all."""
    path = os.fspath(path)
    if not path.endswith(NPZ_SUFFIXES + HDF5_SUFFIXES):
        raise ValueError(f"Expected a path ending in .npz, .h5 or .hdf5, got {path!r}")
    arrays = {"frames": episode.frames, "actions": episode.actions}
    if episode.masks is not None:
        arrays["masks"] = episode.masks
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    try:
        with atomic_path(path) as temporary:
            if path.endswith(NPZ_SUFFIXES):
                np.savez_compressed(temporary, **arrays)  # type: ignore[arg-type]  # numpy's stub: a key might be allow_pickle
            else:
                import h5py

                with h5py.File(temporary, "w") as file:
                    for key, value in arrays.items():
                        file.create_dataset(key, data=value, compression="gzip")
    except OSError as error:  # numpy's and h5py's messages do not name the file
        raise OSError(error.errno, f"Could not write {path}: {error.strerror or error}") from error
    return path


def read_episode_file(path: str | os.PathLike, source: str | None = None, min_frames: int = 2) -> Episode:
    """One episode of the folder format, checked; a damaged file raises ``EpisodeError`` naming ``source``."""
    path = os.fspath(path)
    source = source or path
    with _open_episode_file(path, source) as file:
        arrays = {key: file[key][()] for key in file}
    return make_episode(arrays["frames"], arrays["actions"], arrays.get("masks"), source, min_frames)


def episode_file_shapes(path: str, source: str) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The shapes of an episode file's ``frames`` and ``actions`` arrays, from their headers (nothing decompressed)."""
    with _open_episode_file(path, source) as file:
        if path.endswith(NPZ_SUFFIXES):
            return _npy_shape(file.zip, "frames.npy"), _npy_shape(file.zip, "actions.npy")
        return tuple(file["frames"].shape), tuple(file["actions"].shape)


@contextmanager
def _open_episode_file(path: str, source: str) -> Iterator[Any]:
    """The open ``.npz`` or HDF5 file holding ``frames`` and ``actions``."""
    try:
        with ExitStack() as stack:  # the handle is closed even when numpy cannot read the archive
            if path.endswith(NPZ_SUFFIXES):
                handle = stack.enter_context(open(path, "rb"))
                head = handle.read(6)
                if head == b"\x93NUMPY":
                    raise EpisodeError(f"{source}: a single .npy array, not an .npz archive of 'frames' and 'actions'")
                if head and not head.startswith(b"PK"):  # numpy would try it as a pickle: never for a data file
                    raise EpisodeError(
                        f"{source}: not an episode archive (an .npz is a zip of 'frames' and 'actions' arrays; this "
                        f"file starts with {head!r})"
                    )
                handle.seek(0)
                file = stack.enter_context(np.load(handle, allow_pickle=False))
            else:
                import h5py

                file = stack.enter_context(h5py.File(path, "r"))
            _check_keys(source, list(file))
            yield file
    except EpisodeError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error) as error:
        raise EpisodeError(f"{source}: corrupt or truncated episode file ({error})") from error


def _check_keys(source: str, present: list[str]) -> None:
    missing = [key for key in ("frames", "actions") if key not in present]
    if missing:
        raise EpisodeError(f"{source}: missing {missing}; expected keys 'frames', 'actions' and optionally 'masks'")


def _npy_shape(archive: zipfile.ZipFile, name: str) -> tuple[int, ...]:
    with archive.open(name) as member:
        major, _ = np.lib.format.read_magic(member)
        read_header = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
        return tuple(read_header(member)[0])
