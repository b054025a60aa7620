"""Training windows from datasets larger than memory, through a pool of decoded episodes (see docs/offline.md)."""

from __future__ import annotations

from collections.abc import Generator, Iterator, Sequence
from typing import Any

import numpy as np
import torch as th

from sb3_ef.offline.dataset import EpisodeDataset
from sb3_ef.offline.episodes import Episode, check_length
from sb3_ef.offline.windows import Windows, WindowSampler, window_starts


class EpisodeList(EpisodeDataset):
    """Episodes already in memory, behind the reader interface."""

    def __init__(self, episodes: Sequence[Episode], min_frames: int = 2):
        super().__init__(min_frames)
        self.episodes = list(episodes)

    def __len__(self) -> int:
        return len(self.episodes)

    def _read(self, index: int) -> Episode:
        episode = self.episodes[index]
        check_length(len(episode.frames), self.min_frames, episode.source)
        return episode

    def lengths(self) -> list[int]:
        return [len(episode.frames) for episode in self.episodes]


def episode_bytes(episode: Episode) -> int:
    return sum(array.nbytes for array in (episode.frames, episode.actions, episode.masks) if array is not None)


class StreamingWindowSampler:
    """Windows from episodes ``indices`` of ``dataset``, ``swap`` pool episodes replaced before each batch."""

    def __init__(
        self,
        dataset: EpisodeDataset,
        indices: Sequence[int],
        context: int,
        horizon: int,
        cache_mb: float = 1024,
        swap: int = 1,
        seed: int | None = None,
        lengths: Sequence[int] | None = None,
    ):
        self.dataset, self.indices = dataset, list(indices)
        self.context, self.horizon, self.swap = context, horizon, swap
        if lengths is None:
            all_lengths = dataset.lengths()
            lengths = [all_lengths[i] for i in self.indices]
        self.counts = np.maximum(np.asarray(lengths) - context - horizon + 1, 0)
        if self.counts.sum() == 0:
            raise ValueError(f"No episode has context + horizon = {context + horizon} frames")
        self.first = dataset[self.indices[0]]
        per_frame = episode_bytes(self.first) / len(self.first.frames)
        self.pool_size = max(1, min(len(self.indices), int(cache_mb * 2**20 // (per_frame * np.mean(lengths)))))
        self.streaming = self.pool_size < len(self.indices)
        pool: Any = range(len(self.indices))
        if self.streaming:
            share = self.counts / self.counts.sum()
            pool = np.random.default_rng(seed).choice(len(self.indices), self.pool_size, replace=False, p=share)
        self.pool = [int(i) for i in pool]
        self.sampler = WindowSampler([self._load(i) for i in self.pool], context, horizon, seed)
        self.loaded = len(self.pool)

    def _load(self, position: int) -> Episode:
        return self.dataset[self.indices[position]]  # the dataset checks it against the first episode read

    def sample(self, batch_size: int, device: th.device | str = "cpu") -> Windows:
        if self.streaming:
            for _ in range(self.swap):
                self._swap()
        return self.sampler.sample(batch_size, device)

    def _swap(self) -> None:
        """Replace a random pool episode by one outside the pool, drawn in proportion to its windows."""
        sampler = self.sampler
        weights = self.counts.astype(float)
        weights[self.pool] = 0
        if weights.sum() == 0:
            return
        incoming = int(sampler.rng.choice(len(self.indices), p=weights / weights.sum()))
        slot = int(sampler.rng.integers(len(self.pool)))
        self.pool[slot], sampler.episodes[slot] = incoming, self._load(incoming)
        episode = sampler.episodes[slot]
        sampler.starts[slot] = window_starts(episode, self.context, self.horizon)
        sampler.counts[slot] = len(sampler.starts[slot])
        self.loaded += 1

    @property
    def resident_bytes(self) -> int:
        return sum(episode_bytes(episode) for episode in self.sampler.episodes)


class WindowStream(th.utils.data.IterableDataset):
    """Endless batches for a ``DataLoader``; each worker has its own sampler, seeded ``seed + worker id``."""

    def __init__(self, batch_size: int, workers: int, **sampler: Any):
        super().__init__()
        self.batch_size, self.workers, self.sampler = batch_size, workers, sampler

    def __iter__(self) -> Iterator[Windows]:
        info = th.utils.data.get_worker_info()
        arguments = dict(self.sampler, cache_mb=self.sampler["cache_mb"] / max(self.workers, 1))
        arguments["seed"] += info.id if info is not None else 0
        return _endless(StreamingWindowSampler(**arguments), self.batch_size)


def _endless(sampler: StreamingWindowSampler, batch_size: int) -> Iterator[Windows]:
    while True:
        yield sampler.sample(batch_size)


def window_batches(
    dataset: EpisodeDataset,
    indices: Sequence[int],
    lengths: Sequence[int],
    context: int,
    horizon: int,
    batch_size: int,
    cache_mb: float = 1024,
    workers: int = 0,
    seed: int = 0,
) -> Generator[Windows, None, None]:
    """Endless window batches from ``dataset``: in this process, or decoded in ``workers`` worker processes."""
    sampler: dict[str, Any] = {"dataset": dataset, "indices": list(indices), "context": context, "horizon": horizon}
    sampler.update(lengths=lengths, cache_mb=cache_mb, seed=seed)
    if workers == 0:
        yield from _endless(StreamingWindowSampler(**sampler), batch_size)
    stream = WindowStream(batch_size, workers, **sampler)
    yield from th.utils.data.DataLoader(stream, batch_size=None, num_workers=workers, prefetch_factor=2)
