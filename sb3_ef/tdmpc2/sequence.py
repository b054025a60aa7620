"""A TD-MPC2 training batch laid out over time: the replay window rebuilt into stacked observations and augmented."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import torch as th

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.common.env_checks import FRAME_CHANNELS

#: Pixels of TD-MPC2's random shift.
SHIFT_PAD = 3


class Sequence(NamedTuple):
    first: th.Tensor  # (B, C, h, w) augmented observation at t
    following: th.Tensor  # (H, B, C, h, w) augmented observations at t+1 .. t+H
    actions: th.Tensor  # (H, B, A)
    rewards: th.Tensor  # (H, B)
    valid: th.Tensor  # (H, B) float: step t+i was taken inside the episode
    auxiliary_targets: Any  # the auxiliary loss's targets, augmented with ``first``; None without one


def training_sequence(
    batch: SequenceReplayBufferSamples,
    horizon: int,
    augment_first: Callable[[SequenceReplayBufferSamples], tuple[th.Tensor, Any]],
) -> Sequence:
    """The first ``horizon`` steps of ``batch``'s windows, shifted; the one at t augmented by ``augment_first``."""
    observations = batch.observations
    size, channels, height, width = observations.shape
    stack = channels // FRAME_CHANNELS
    frames = th.cat(
        [observations.view(size, stack, FRAME_CHANNELS, height, width), batch.future_frames[:, :horizon]], dim=1
    )
    following = th.stack([frames[:, t : t + stack].flatten(1, 2) for t in range(1, horizon + 1)])
    (following,) = random_shift(following.flatten(0, 1), pad=SHIFT_PAD)
    valid = batch.future_mask[:, :horizon].float().cumprod(dim=1).T
    first, auxiliary_targets = augment_first(batch)
    return Sequence(
        first=first,
        following=following.unflatten(0, (horizon, size)),
        actions=batch.future_actions[:, :horizon].transpose(0, 1),
        rewards=batch.future_rewards[:, :horizon].T,
        valid=valid,
        auxiliary_targets=auxiliary_targets,
    )


def masked_mean(values: th.Tensor, valid: th.Tensor) -> th.Tensor:
    """Mean over the batch (last axis) of the valid entries, per leading index: ``(T, B) -> (T,)``."""
    return (values * valid).sum(-1) / valid.sum(-1).clamp(min=1.0)
