"""The body-schema measures on constructed cases: saliency shares, region errors against the copy baseline, and
the window rules."""

import numpy as np
import pytest
from body_schema import (
    RegionErrors,
    cut_region_windows,
    dilate,
    saliency_share,
    saliency_shares,
    tint,
)
from scripted import ScriptedEpisode, figure_eight_probe


def test_saliency_share_is_the_masked_part_of_the_total():
    saliency = np.zeros((4, 4))
    saliency[0, :2] = [3.0, 1.0]  # inside the mask: 4
    saliency[3, 3] = 4.0  # outside: 4
    mask = np.zeros((4, 4), bool)
    mask[:2, :2] = True
    assert saliency_share(saliency, mask) == pytest.approx(0.5)
    assert saliency_share(saliency, np.ones((4, 4), bool)) == pytest.approx(1.0)
    assert np.isnan(saliency_share(np.zeros((4, 4)), mask))
    with pytest.raises(ValueError, match="non-negative"):
        saliency_share(-saliency, mask)
    with pytest.raises(TypeError, match="boolean"):
        saliency_share(saliency, mask.astype(int))
    with pytest.raises(ValueError, match="same shape"):
        saliency_share(saliency, mask[:3])


def test_saliency_shares_enrichment_is_share_over_area():
    maps = np.ones((2, 4, 4))  # a flat map: every region gets exactly its area
    maps[1, 0, 0] = 13.0  # second map: pixel (0, 0) holds 13 of 28
    region = np.zeros((2, 4, 4), bool)
    region[:, 0, 0] = True
    scores = saliency_shares(maps, {"tool": region, "rest": ~region})
    assert scores["tool"]["fraction"] == pytest.approx(1 / 16)
    assert scores["tool"]["share"] == pytest.approx((1 / 16 + 13 / 28) / 2)
    assert scores["tool"]["enrichment"] == pytest.approx(scores["tool"]["share"] * 16)
    assert scores["rest"]["share"] + scores["tool"]["share"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="do not match"):
        saliency_shares(maps, {"tool": region[:1]})


def _moving_square(offsets: list[int], size: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Frames (T, 3, s, s) in [0, 1] of a white 2x2 square at column ``offset`` on black, and its masks (T, s, s)."""
    frames = np.zeros((len(offsets), 3, size, size))
    masks = np.zeros((len(offsets), size, size), bool)
    for index, offset in enumerate(offsets):
        frames[index, :, 3:5, offset : offset + 2] = 1.0
        masks[index, 3:5, offset : offset + 2] = True
    return frames, masks


def test_region_errors_against_the_copy_baseline():
    frames, masks = _moving_square([0, 2, 4])  # t, t + 1, t + 2: the square jumps two columns per step
    truth, last = frames[None, 1:], frames[None, 0]
    region_masks = {"square": masks[None]}

    perfect = RegionErrors()
    perfect.add(truth, truth, last, region_masks)
    copy = RegionErrors()
    copy.add(np.broadcast_to(last[:, None], truth.shape), truth, last, region_masks)
    blank = RegionErrors()
    blank.add(np.zeros_like(truth), truth, last, region_masks)

    # Region at k: the square at t or at t + k, 8 pixels; the copy is wrong on all 8 (squared error 1 each).
    assert perfect.scores()["square"]["model_mse"] == 0.0
    assert perfect.scores()["square"]["ratio"] == 0.0
    scores = copy.scores()["square"]
    assert scores["model_mse"] == scores["copy_mse"] == pytest.approx(1.0)
    assert scores["ratio"] == pytest.approx(1.0) and scores["ratio_per_k"] == pytest.approx([1.0, 1.0])
    assert scores["pixels"] == 16
    # An all-black prediction misses only the 4 pixels where the square is at t + k.
    assert blank.scores()["square"]["ratio"] == pytest.approx(0.5)


def test_region_errors_pool_pixels_over_batches_and_leave_a_static_region_without_ratio():
    frames, masks = _moving_square([0, 0, 0])
    errors = RegionErrors()
    errors.add(frames[None, 1:] * 0.5, frames[None, 1:], frames[None, 0], {"square": masks[None]})
    scores = errors.scores()["square"]
    assert scores["copy_mse"] == 0.0 and np.isnan(scores["ratio"])
    assert scores["model_mse"] == pytest.approx(0.25)
    errors.add(frames[None, 1:], frames[None, 1:], frames[None, 0], {"square": masks[None]})
    assert errors.scores()["square"]["model_mse"] == pytest.approx(0.125)  # 8 pixels at 0.25, 8 at 0


def test_region_errors_check_shapes():
    frames, masks = _moving_square([0, 2, 4])
    errors = RegionErrors()
    with pytest.raises(ValueError, match=r"\(N, H, 3, h, w\)"):
        errors.add(frames[1:], frames[1:], frames[0], {"square": masks})
    with pytest.raises(ValueError, match="bool masks"):
        errors.add(frames[None, 1:], frames[None, 1:], frames[None, 0], {"square": masks[None, 1:]})


def _episode(attached: list[bool], steps: int = 6) -> ScriptedEpisode:
    frames = np.arange(steps + 1, dtype=np.uint8)[:, None, None, None] * np.ones((1, 3, 4, 4), np.uint8)
    positions = np.zeros((steps + 1, 3))
    positions[:, 0] = np.arange(steps + 1) * 0.01
    return ScriptedEpisode(
        scenario="constructed",
        frames=frames,
        actions=np.arange(steps, dtype=np.float32)[:, None] * np.ones((1, 4), np.float32),
        masks={"agent": np.zeros((steps + 1, 4, 4), bool), "tool": np.ones((steps + 1, 4, 4), bool)},
        hand=positions,
        object=positions,
        attached=np.array(attached),
        reset_seed=0,
    )


def test_windows_follow_the_attachment_rule():
    episode = _episode([True, True, True, True, False, True, True])
    every = cut_region_windows([episode], context=2, horizon=2)
    assert len(every) == 4  # t = 1..4 (the last t leaves H = 2 frames after it)
    np.testing.assert_array_equal(every.observations[0, ::3, 0, 0], [0, 1])  # frames t - 1, t, oldest first
    np.testing.assert_array_equal(every.frames[0, :, 0, 0, 0], [2, 3])
    np.testing.assert_array_equal(every.actions[0, :, 0], [1, 2])
    assert every.masks["tool"].shape == (4, 3, 4, 4)
    np.testing.assert_allclose(every.motion, 0.02)
    context = cut_region_windows([episode], context=2, horizon=2, require_attached="context")
    np.testing.assert_array_equal(context.observations[:, -3, 0, 0], [1, 2, 3])  # t = 4: not attached
    window = cut_region_windows([episode], context=2, horizon=2, require_attached="window")
    np.testing.assert_array_equal(window.observations[:, -3, 0, 0], [1])  # frames 0..3 only
    assert len(cut_region_windows([episode], context=2, horizon=2, stride=2)) == 2
    with pytest.raises(ValueError, match="require_attached"):
        cut_region_windows([episode], 2, 2, require_attached="always")
    with pytest.raises(ValueError, match="No window"):
        cut_region_windows([_episode([False] * 7)], 2, 2, require_attached="window")


def test_tint_blends_only_the_masked_pixels():
    frame = np.full((2, 2, 3), 100, np.uint8)
    mask = np.array([[True, False], [False, False]])
    tinted = tint(frame, mask, (0, 200, 0), alpha=0.5)
    np.testing.assert_array_equal(tinted[0, 0], [50, 150, 50])
    np.testing.assert_array_equal(tinted[1], frame[1])


def test_dilate_grows_a_mask_by_a_square_neighbourhood():
    mask = np.zeros((2, 5, 5), bool)
    mask[0, 2, 2] = True
    grown = dilate(mask, 1)
    np.testing.assert_array_equal(grown[0, 1:4, 1:4], True)
    assert grown[0].sum() == 9 and not grown[1].any()
    np.testing.assert_array_equal(dilate(mask, 0), mask)
    assert dilate(mask, 2)[0].all()  # radius 2 from the centre covers the 5x5 frame
    with pytest.raises(ValueError, match="radius"):
        dilate(mask, -1)


def test_figure_eight_probe_moves_in_the_plane_with_the_gripper_closed():
    actions = figure_eight_probe(20)
    assert actions.shape == (20, 4) and actions.dtype == np.float32
    np.testing.assert_array_equal(actions[:, 2:], [[0.0, 1.0]] * 20)
    np.testing.assert_allclose(actions[:, :2].sum(axis=0), 0.0, atol=1e-5)  # one period: back to the start
    assert len(np.unique(actions[:, 0])) > 2  # smooth values, not the babbling's signs
