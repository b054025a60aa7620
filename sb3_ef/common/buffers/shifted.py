"""A sequence replay buffer whose samples are random-shifted, for hosts whose ``train()`` samples the buffer itself."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import torch as th
from stable_baselines3.common.vec_env import VecNormalize

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers.sampling import SequenceReplayBufferSamples
from sb3_ef.common.buffers.sequence import SequenceReplayBuffer


def augment_frames(
    batch: SequenceReplayBufferSamples, augment: Callable[..., tuple[th.Tensor, ...]]
) -> SequenceReplayBufferSamples:
    """``batch`` augmented by ``augment``: observations and future frames alike, the next observations apart."""
    horizon = batch.future_frames.shape[1]
    observations, future_frames = augment(batch.observations, batch.future_frames.flatten(1, 2))
    (next_observations,) = augment(batch.next_observations)
    return batch._replace(
        observations=observations,
        next_observations=next_observations,
        future_frames=future_frames.unflatten(1, (horizon, -1)),
    )


class ShiftedSequenceReplayBuffer(SequenceReplayBuffer):
    """:class:`SequenceReplayBuffer` whose samples are random-shifted as in DrQ, for SAC, TD3 and TQC.

    :param shift_pad: the largest shift in pixels; the other arguments are :class:`SequenceReplayBuffer`'s.
    """

    def __init__(self, *args: Any, shift_pad: int = 4, **kwargs: Any):
        if shift_pad < 0:
            raise ValueError(f"shift_pad must be >= 0, got {shift_pad}")
        super().__init__(*args, **kwargs)
        self.shift_pad = shift_pad

    def sample(  # type: ignore[override]  # SB3's ReplayBufferSamples, a NamedTuple, cannot be extended
        self, batch_size: int, env: VecNormalize | None = None
    ) -> SequenceReplayBufferSamples:
        return augment_frames(super().sample(batch_size, env), partial(random_shift, pad=self.shift_pad))
