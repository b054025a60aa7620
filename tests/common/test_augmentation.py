import pytest
import torch as th
from torch.nn import functional as F

from sb3_ef.common.augmentation import random_shift


def _pad_and_crop(images: th.Tensor, offsets: th.Tensor, pad: int) -> th.Tensor:
    """The textbook definition: replicate-pad, then crop at (pad + offset)."""
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    height, width = images.shape[-2:]
    crops = [
        padded[i, :, pad + dy : pad + dy + height, pad + dx : pad + dx + width]
        for i, (dy, dx) in enumerate(offsets.tolist())
    ]
    return th.stack(crops)


def test_matches_pad_and_crop():
    images = th.rand(6, 9, 20, 20)
    (shifted,) = random_shift(images, pad=4, generator=th.Generator().manual_seed(3))
    offsets = th.randint(0, 9, (6, 2), generator=th.Generator().manual_seed(3)) - 4
    assert th.equal(shifted, _pad_and_crop(images, offsets, pad=4))


def test_shift_is_shared_between_tensors_and_keeps_dtype():
    context = th.randint(0, 256, (8, 9, 16, 16), dtype=th.uint8)
    target = context[:, -3:].clone()
    shifted_context, shifted_target = random_shift(context, target, pad=3)
    assert shifted_context.dtype == th.uint8
    assert th.equal(shifted_context[:, -3:], shifted_target)


def test_shifts_differ_between_samples():
    images = th.arange(16.0).repeat(64, 1, 16, 1)  # each row counts 0..15 along the width
    (shifted,) = random_shift(images, pad=4)
    first_columns = shifted[:, 0, 0, 0].unique()
    assert len(first_columns) > 1


def test_zero_pad_is_identity():
    images = th.rand(2, 3, 8, 8)
    (shifted,) = random_shift(images, pad=0)
    assert th.equal(shifted, images)


def test_mismatched_shapes_raise():
    with pytest.raises(ValueError, match=r"\(batch, channels, 8, 8\)"):
        random_shift(th.rand(2, 3, 8, 8), th.rand(2, 3, 6, 6))
    with pytest.raises(ValueError, match="at least one"):
        random_shift()
