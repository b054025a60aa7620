"""Training windows cut from episodes: ``context`` stacked frames, the next ``horizon`` actions and frames."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th

from sb3_ef.offline.episodes import Episode


@dataclass(frozen=True)
class Windows:
    """A batch of windows: ``observations`` uint8 (B, 3 * context, H, W) oldest first, ``actions`` (B, H, A),
    ``frames`` t + 1 .. t + H uint8 (B, H, 3, H, W), ``masks`` bool (B, H + 1, H, W) of frames t .. t + H or None."""

    observations: th.Tensor
    actions: th.Tensor
    frames: th.Tensor
    masks: th.Tensor | None


def window_starts(episode: Episode, context: int, horizon: int) -> np.ndarray:
    """Every valid t (the last context frame): ``context - 1 <= t <= T - horizon``."""
    return np.arange(context - 1, episode.steps - horizon + 1)


def cut_windows(
    episodes: list[Episode], picks: list[tuple[int, int]], context: int, horizon: int, device: th.device | str = "cpu"
) -> Windows:
    """Windows at ``picks`` = [(episode index, t), ...]."""
    observations, actions, frames, masks = [], [], [], []
    with_masks = all(episodes[index].masks is not None for index, _ in picks)
    for index, t in picks:
        episode = episodes[index]
        observations.append(episode.frames[t - context + 1 : t + 1].reshape(-1, *episode.frames.shape[2:]))
        actions.append(episode.actions[t : t + horizon])
        frames.append(episode.frames[t + 1 : t + horizon + 1])
        if with_masks:
            masks.append(episode.masks[t : t + horizon + 1])  # type: ignore[index]
    return Windows(
        th.as_tensor(np.stack(observations)).to(device),
        th.as_tensor(np.stack(actions)).to(device),
        th.as_tensor(np.stack(frames)).to(device),
        th.as_tensor(np.stack(masks)).to(device) if with_masks else None,
    )


class WindowSampler:
    """Draws windows uniformly over every valid (episode, t) of a list of episodes."""

    def __init__(self, episodes: list[Episode], context: int, horizon: int, seed: int | None = None):
        self.episodes, self.context, self.horizon = episodes, context, horizon
        self.starts = [window_starts(episode, context, horizon) for episode in episodes]
        self.counts = np.array([len(starts) for starts in self.starts])
        if self.counts.sum() == 0:
            raise ValueError(f"No episode has context + horizon = {context + horizon} frames")
        self.rng = np.random.default_rng(seed)

    def sample(self, batch_size: int, device: th.device | str = "cpu") -> Windows:
        flat = self.rng.integers(0, self.counts.sum(), batch_size)
        bounds = np.cumsum(self.counts)
        episode_indices = np.searchsorted(bounds, flat, side="right")
        offsets = flat - (bounds - self.counts)[episode_indices]
        picks = [(int(e), int(self.starts[e][o])) for e, o in zip(episode_indices, offsets, strict=True)]
        return cut_windows(self.episodes, picks, self.context, self.horizon, device)
