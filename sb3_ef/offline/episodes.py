"""One episode of robot video with actions, the checks every reader applies, and the folder format's writer.

The episode contract: ``frames`` uint8 (T + 1, 3, H, W), channels-first, frame ``t`` is what the camera saw before
action ``t``; ``actions`` float32 (T, action_dim); ``masks`` optional bool (T + 1, H, W), the agent's pixels in each
frame. Readers also accept T frames for T actions (the convention of BAIR's files: the last action has no frame
after it) and then drop the last action.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from sb3_ef.common.env_checks import FRAME_CHANNELS

#: File suffixes of the folder format.
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
    """Check one episode's arrays and return it as an :class:`Episode`.

    :param source: where it comes from (file and episode), quoted in every error.
    :param min_frames: the fewest frames accepted (context + horizon for training).
    :raises EpisodeError: naming ``source``, what was expected and what was received.
    """
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
    if len(frames) < min_frames:
        raise EpisodeError(
            f"{source}: episode of {len(frames)} frames is shorter than context + horizon = {min_frames} frames"
        )
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


def write_episode(path: str | os.PathLike, episode: Episode) -> str:
    """Write one episode in the folder format: ``.npz`` (compressed) or ``.h5`` / ``.hdf5`` by suffix."""
    path = os.fspath(path)
    arrays = {"frames": episode.frames, "actions": episode.actions}
    if episode.masks is not None:
        arrays["masks"] = episode.masks
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    if path.endswith(NPZ_SUFFIXES):
        np.savez_compressed(path, **arrays)  # type: ignore[arg-type]  # numpy's stub: a key might be allow_pickle
    elif path.endswith(HDF5_SUFFIXES):
        import h5py

        with h5py.File(path, "w") as file:
            for key, value in arrays.items():
                file.create_dataset(key, data=value, compression="gzip")
    else:
        raise ValueError(f"Expected a path ending in .npz, .h5 or .hdf5, got {path!r}")
    return path
