"""Random-shift image augmentation (DrQ / DrQ-v2)."""

from __future__ import annotations

import torch as th


def random_shift(*images: th.Tensor, pad: int = 4, generator: th.Generator | None = None) -> tuple[th.Tensor, ...]:
    """Shift each sample of a batch by a random integer offset in ``[-pad, pad]`` pixels per axis.

    Equivalent to replicate-padding by ``pad`` and taking a random crop of the original size, which is what
    DrQ-v2 does with ``grid_sample`` at integer offsets. Implemented with clamped index gathering, so it works
    on any dtype (uint8 included) without padding copies.

    All tensors passed together get the *same* shift per sample: pass the context observation and the
    Ego-Foresight target frame in one call so both move together.

    :param images: tensors of shape (batch, channels, height, width), all with the same batch, height and width.
    :param pad: maximum shift in pixels.
    :param generator: optional torch generator for reproducible shifts.
    :return: the shifted tensors, in the order given.
    """
    if not images:
        raise ValueError("random_shift needs at least one tensor")
    batch, _, height, width = images[0].shape
    for image in images:
        if image.dim() != 4 or image.shape[0] != batch or image.shape[-2:] != (height, width):
            raise ValueError(
                f"random_shift expects (batch, channels, {height}, {width}) tensors with batch {batch}, "
                f"got shape {tuple(image.shape)}"
            )
    device = images[0].device
    offsets = th.randint(0, 2 * pad + 1, (batch, 2), device=device, generator=generator) - pad
    rows = (th.arange(height, device=device)[None, :] + offsets[:, :1]).clamp_(0, height - 1)
    cols = (th.arange(width, device=device)[None, :] + offsets[:, 1:]).clamp_(0, width - 1)
    batch_index = th.arange(batch, device=device)[:, None, None]
    shifted = []
    for image in images:
        # (batch, height, width, channels) after advanced indexing on the spatial axes, then back to channels-first.
        moved = image.permute(0, 2, 3, 1)[batch_index, rows[:, :, None], cols[:, None, :]]
        shifted.append(moved.permute(0, 3, 1, 2).contiguous())
    return tuple(shifted)
