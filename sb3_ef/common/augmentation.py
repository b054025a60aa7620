"""Image augmentations: DrQ's random shift, CURL's random and centre crops."""

from __future__ import annotations

import torch as th


def random_shift(*images: th.Tensor, pad: int = 4, generator: th.Generator | None = None) -> tuple[th.Tensor, ...]:
    """Shift each sample by a random integer offset in ``[-pad, pad]`` pixels per axis, as DrQ-v2's replicate-pad
    and crop, by clamped index gathering (any dtype). Tensors passed together get the same shift per sample.

    :param images: tensors of shape (batch, channels, height, width), all with the same batch, height and width.
    :param pad: maximum shift in pixels.
    :param generator: optional torch generator for reproducible shifts.
    :return: the shifted tensors, in the order given.
    """
    batch, height, width = _check_batch(images, "random_shift")
    device = images[0].device
    offsets = _draw(0, 2 * pad + 1, (batch, 2), device, generator) - pad
    rows = (th.arange(height, device=device)[None, :] + offsets[:, :1]).clamp_(0, height - 1)
    cols = (th.arange(width, device=device)[None, :] + offsets[:, 1:]).clamp_(0, width - 1)
    return _gather(images, rows, cols)


def _draw(low: int, high: int, shape: tuple[int, ...], device: th.device, generator: th.Generator | None) -> th.Tensor:
    """Integers in ``[low, high)`` on ``device``, drawn on the generator's device (a CPU generator cannot draw on a
    GPU)."""
    draw_device = device if generator is None else generator.device
    return th.randint(low, high, shape, device=draw_device, generator=generator).to(device)


def _gather(images: tuple[th.Tensor, ...], rows: th.Tensor, cols: th.Tensor) -> tuple[th.Tensor, ...]:
    """Each image's pixels at the per-sample rows ``(batch, out_height)`` and columns ``(batch, out_width)``."""
    batch_index = th.arange(rows.shape[0], device=rows.device)[:, None, None]
    return tuple(
        image.permute(0, 2, 3, 1)[batch_index, rows[:, :, None], cols[:, None, :]].permute(0, 3, 1, 2).contiguous()
        for image in images
    )


def _check_batch(images: tuple[th.Tensor, ...], name: str) -> tuple[int, int, int]:
    """(batch, height, width) shared by all ``images``, or a ``ValueError`` naming the first that differs."""
    if not images:
        raise ValueError(f"{name} needs at least one tensor")
    batch, height, width = images[0].shape[0], images[0].shape[-2], images[0].shape[-1]
    for image in images:
        if image.dim() != 4 or image.shape[0] != batch or image.shape[-2:] != (height, width):
            raise ValueError(
                f"{name} expects (batch, channels, {height}, {width}) tensors with one batch size and frame size "
                f"(batch {batch}), got shapes {[tuple(image.shape) for image in images]}"
            )
    return batch, height, width


def _check_crop(size: int, height: int, width: int, name: str) -> None:
    if isinstance(size, bool) or not isinstance(size, int) or not 1 <= size <= min(height, width):
        raise ValueError(
            f"{name}: crop size must be an int in [1, {min(height, width)}] for {height}x{width} frames, got {size!r}"
        )


def random_crop(
    *images: th.Tensor, size: int, generator: th.Generator | None = None, last_offset: bool = True
) -> tuple[th.Tensor, ...]:
    """Crop a random ``size`` x ``size`` window of each sample (CURL's augmentation), its corner uniform over every
    position that fits; ``last_offset=False`` leaves out the last (as CURL's authors draw it). Tensors passed
    together get the same window per sample.

    :param images: tensors of shape (batch, channels, height, width), all with the same batch, height and width.
    :param size: side of the crop, at most the frame's height and width.
    :param generator: optional torch generator for reproducible crops.
    :param last_offset: whether the corner may take the last offset that fits.
    :return: the cropped tensors (batch, channels, size, size), in the order given.
    """
    batch, height, width = _check_batch(images, "random_crop")
    _check_crop(size, height, width, "random_crop")
    device = images[0].device
    end = 1 if last_offset else 0
    top = _draw(0, max(height - size + end, 1), (batch, 1), device, generator)
    left = _draw(0, max(width - size + end, 1), (batch, 1), device, generator)
    window = th.arange(size, device=device)[None, :]
    return _gather(images, top + window, left + window)


def center_crop(images: th.Tensor, size: int) -> th.Tensor:
    """The central ``size`` x ``size`` window of (batch, channels, height, width) ``images`` (CURL's when acting)."""
    _, height, width = _check_batch((images,), "center_crop")
    _check_crop(size, height, width, "center_crop")
    top, left = (height - size) // 2, (width - size) // 2
    return images[:, :, top : top + size, left : left + size]
