"""CURL's random crop (sb3_ef.curl.crop, the authors' offsets) and random_crop / center_crop
(sb3_ef.common.augmentation: every window that fits, and CURL's acting crop)."""

from __future__ import annotations

import pytest
import torch as th

from sb3_ef.common.augmentation import center_crop, random_crop
from sb3_ef.curl.crop import random_crops


def test_tensors_cropped_together_share_each_samples_window_and_every_window_occurs():
    rows = th.arange(10).view(1, 1, 10, 1).expand(400, 1, 10, 10)
    cols = th.arange(10).view(1, 1, 1, 10).expand(400, 2, 10, 10)
    cropped_rows, cropped_cols = random_crop(rows, cols, size=7, generator=th.Generator().manual_seed(0))
    assert cropped_rows.shape == (400, 1, 7, 7) and cropped_cols.shape == (400, 2, 7, 7)
    tops, lefts = cropped_rows[:, 0, 0, 0], cropped_cols[:, 0, 0, 0]
    # A window is a contiguous block: row r + i and column c + j at (i, j).
    assert th.equal(cropped_rows, tops.view(-1, 1, 1, 1) + th.arange(7).view(1, 1, 7, 1).expand(400, 1, 7, 7))
    assert th.equal(cropped_cols, lefts.view(-1, 1, 1, 1) + th.arange(7).view(1, 1, 1, 7).expand(400, 2, 7, 7))
    # Corners are drawn over every position that fits, 0 .. 10 - 7 inclusive.
    assert set(tops.tolist()) == set(lefts.tolist()) == {0, 1, 2, 3}


def test_curls_crop_draws_the_authors_offsets_0_to_frame_minus_crop_minus_1():
    rows = th.arange(100).view(1, 1, 100, 1).expand(2000, 1, 100, 100)
    cols = th.arange(100).view(1, 1, 1, 100).expand(2000, 1, 100, 100)
    images = th.cat([rows, cols], dim=1).to(th.uint8)
    cropped = random_crops(images, 84, generator=th.Generator().manual_seed(0))
    tops, lefts = cropped[:, 0, 0, 0], cropped[:, 1, 0, 0]
    assert th.equal(cropped[:, 0], (tops.view(-1, 1, 1) + th.arange(84).view(1, 84, 1)).expand(-1, 84, 84))
    assert th.equal(cropped[:, 1], (lefts.view(-1, 1, 1) + th.arange(84).view(1, 1, 84)).expand(-1, 84, 84))
    # np.random.randint(0, 100 - 84): 0 .. 15, never 16.
    assert set(tops.tolist()) == set(lefts.tolist()) == set(range(16))
    whole = th.zeros(2, 3, 84, 84, dtype=th.uint8)
    assert random_crops(whole, 84) is whole  # frames the size of the crop (the authors' draw is undefined there)
    with pytest.raises(ValueError, match=r"crop_size must be an int in \[1, 84\].*got 85"):
        random_crops(whole, 85)


def test_center_crop_takes_the_middle_window():
    images = th.arange(2 * 3 * 100 * 100).view(2, 3, 100, 100)
    assert th.equal(center_crop(images, 84), images[:, :, 8:92, 8:92])
    assert th.equal(center_crop(images[:, :, :, :99], 84), images[:, :, 8:92, 7:91])


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (
            lambda: random_crop(th.zeros(2, 3, 8, 8), size=9),
            r"crop size must be an int in \[1, 8\] for 8x8 frames, got 9",
        ),
        (lambda: random_crop(th.zeros(2, 3, 8, 8), size=0), r"got 0"),
        (lambda: center_crop(th.zeros(2, 3, 8, 6), 7), r"\[1, 6\] for 8x6 frames, got 7"),
        (lambda: random_crop(th.zeros(2, 3, 8, 8), th.zeros(3, 1, 8, 8), size=4), r"one batch size and frame size"),
        (lambda: random_crop(size=4), r"needs at least one tensor"),
    ],
)
def test_bad_crops_are_refused_with_the_cause_named(call, message):
    with pytest.raises(ValueError, match=message):
        call()
