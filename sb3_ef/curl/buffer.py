"""A sequence replay buffer that can hand out random crops of its frames, for CURL's host updates."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any

from stable_baselines3.common.vec_env import VecNormalize

from sb3_ef.common.augmentation import augment_frames, random_crop
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples


class CroppedSequenceReplayBuffer(SequenceReplayBuffer):
    """:class:`SequenceReplayBuffer` whose samples, inside :meth:`cropping`, are random ``crop_size`` crops: each
    sample's observations (with its future frames) get one window, its next observations another, as CURL crops
    ``obs`` and ``next_obs`` independently. Outside the block the samples are whole frames, which CURL's own loss
    crops twice. Gives SB3's SAC CURL's augmentation without changing its ``train()``.

    :param crop_size: side of the crops, at most the frames' height and width; the other arguments are
        :class:`SequenceReplayBuffer`'s.
    """

    def __init__(self, *args: Any, crop_size: int, **kwargs: Any):
        super().__init__(*args, **kwargs)
        _, height, width = self.obs_shape
        if isinstance(crop_size, bool) or not isinstance(crop_size, int) or not 1 <= crop_size <= min(height, width):
            raise ValueError(
                f"crop_size must be an int in [1, {min(height, width)}] (at most the {height}x{width} frames), "
                f"got {crop_size!r}"
            )
        self.crop_size = crop_size
        self._cropping = False

    @contextmanager
    def cropping(self) -> Iterator[None]:
        """Inside the block, :meth:`sample` returns random crops."""
        self._cropping = True
        try:
            yield
        finally:
            self._cropping = False

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> SequenceReplayBufferSamples:  # type: ignore[override]
        batch = super().sample(batch_size, env)
        if not self._cropping:
            return batch
        return augment_frames(batch, partial(random_crop, size=self.crop_size))
