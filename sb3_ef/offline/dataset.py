"""``EpisodeDataset``: the interface every episode reader implements, and the checks and decoding they share."""

from __future__ import annotations

import io
from abc import ABC, abstractmethod
from collections.abc import Iterator
from typing import Any, Literal, overload

import numpy as np

from sb3_ef.offline.episodes import Episode, EpisodeError


def check_like(episode: Episode, first: Episode) -> Episode:
    """``episode`` if its frame shape and action size equal ``first``'s, else an ``EpisodeError`` naming both."""
    if episode.frame_shape != first.frame_shape or episode.action_dim != first.action_dim:
        raise EpisodeError(
            f"{episode.source}: frames {episode.frame_shape} and {episode.action_dim}-d actions differ from "
            f"{first.source}: frames {first.frame_shape} and {first.action_dim}-d actions (the episodes of a dataset "
            "share one frame shape and action size; readers with image_size= resize them)"
        )
    return episode


def decode_image(data: bytes, image_size: int | None, error: str) -> np.ndarray:
    """A JPEG / PNG as uint8 (3, H, W), resized to ``image_size`` squared when given; ``error`` names a bad one."""
    from PIL import Image

    try:
        image = Image.open(io.BytesIO(data)).convert("RGB")
    except Exception as exception:
        raise EpisodeError(error) from exception
    if image_size:
        image = image.resize((image_size, image_size), Image.Resampling.BILINEAR)
    return np.asarray(image).transpose(2, 0, 1)


@overload
def check_image_size(image_size: Any, optional: Literal[False]) -> int: ...


@overload
def check_image_size(image_size: Any, optional: bool = True) -> int | None: ...


def check_image_size(image_size: Any, optional: bool = True) -> int | None:
    """``image_size`` if it is a positive number of pixels (or None when ``optional``), else a ``ValueError``."""
    if image_size is None and optional:
        return None
    if isinstance(image_size, bool) or not isinstance(image_size, int) or image_size < 1:
        keep = " or None to keep the camera's size" if optional else ""
        raise ValueError(f"image_size must be a positive number of pixels (frames of N x N){keep}, got {image_size!r}")
    return image_size


class EpisodeDataset(ABC):
    """Episodes read on demand; subclasses implement ``__len__`` and ``_read(index)``."""

    def __init__(self, min_frames: int = 2):
        self.min_frames = min_frames
        self._first: Episode | None = None

    @abstractmethod
    def __len__(self) -> int: ...

    @abstractmethod
    def _read(self, index: int) -> Episode:
        """Episode ``index`` (already range-checked), read and checked."""

    def __getitem__(self, index: int) -> Episode:
        """Episode ``index``; it must have the frame shape and action size of the first episode read."""
        if not 0 <= index < len(self):
            raise IndexError(f"Episode index {index} out of range for a dataset of {len(self)} episodes")
        episode = self._read(index)
        if self._first is None:
            self._first = Episode(episode.frames[:1].copy(), episode.actions[:1].copy(), None, episode.source)  # shapes
        return check_like(episode, self._first)

    def __iter__(self) -> Iterator[Episode]:
        for index in range(len(self)):
            yield self[index]

    def lengths(self) -> list[int]:
        """Frames per episode, to index the dataset for streaming (here by reading each episode once)."""
        return [len(episode.frames) for episode in self]
