"""CURL's random crop, as the authors draw it: one window per sample, its corner in ``[0, frame - size)``."""

from __future__ import annotations

import torch as th

from sb3_ef.common.augmentation import random_crop


def check_crop_size(crop_size: object, height: int, width: int, who: str) -> int:
    """``crop_size`` if it is an int in ``[1, min(height, width)]``, else a ``ValueError`` naming both sizes."""
    if isinstance(crop_size, bool) or not isinstance(crop_size, int) or not 1 <= crop_size <= min(height, width):
        raise ValueError(
            f"{who}'s crop_size must be an int in [1, {min(height, width)}] (at most the {height}x{width} frames: "
            f"render larger frames, e.g. make_env(..., size=100) for crops of 84), got {crop_size!r}"
        )
    return crop_size


def random_crops(images: th.Tensor, size: int, generator: th.Generator | None = None) -> th.Tensor:
    """A random ``size`` x ``size`` window of each image, the corner drawn as the authors' ``np.random.randint``."""
    if images.dim() != 4:
        raise ValueError(f"CURL crops (batch, channels, height, width) frames, got shape {tuple(images.shape)}")
    _, _, height, width = images.shape
    check_crop_size(size, height, width, "CURL")
    if (height, width) == (size, size):
        return images
    (cropped,) = random_crop(images, size=size, generator=generator, last_offset=False)
    return cropped
