"""``EpisodeDataset``: the interface every episode reader implements, and the checks all readers share.

A dataset's episodes must share one frame shape and one action size (a model is trained on one). Each reader only
reads episode ``i`` (``_read``); ``dataset[i]`` adds the index check and compares the episode with the first one
read from the dataset, so that a folder mixing 64x64 and 32x32 episodes raises when the odd one is read.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterator
from typing import Any, Literal, overload

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
    """A sequence of episodes: ``len(dataset)``, ``dataset[i]`` and iteration, each read on demand.

    Subclasses implement ``__len__`` and ``_read(index)`` (read and check one episode with
    :func:`~sb3_ef.offline.episodes.make_episode`).

    :param min_frames: the fewest frames an episode may have (context + horizon); shorter ones raise.
    """

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
        """Frames per episode, to index the dataset for streaming. Readers that know them from metadata or headers
        override this; here every episode is read once (and let go)."""
        return [len(episode.frames) for episode in self]
