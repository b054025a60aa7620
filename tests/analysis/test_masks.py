import numpy as np
import pytest

from sb3_ef.analysis.masks import mask_scores, threshold_saliency


def test_scores_on_hand_counted_masks():
    target = np.zeros((4, 4), dtype=bool)
    target[:2, :2] = True  # 4 agent pixels
    predicted = np.zeros((4, 4), dtype=bool)
    predicted[1:3, 1:3] = True  # 4 predicted, overlapping target only at (1, 1)
    scores = mask_scores(predicted, target)
    # TP = 1, FP = 3, FN = 3: precision 1/4, recall 1/4, IoU 1/7
    assert scores.precision == pytest.approx(0.25)
    assert scores.recall == pytest.approx(0.25)
    assert scores.iou == pytest.approx(1 / 7)


def test_perfect_and_undefined_scores():
    target = np.eye(5, dtype=bool)
    assert mask_scores(target, target).as_dict() == {"precision": 1.0, "recall": 1.0, "iou": 1.0}
    empty = np.zeros_like(target)
    scores = mask_scores(empty, target)
    assert np.isnan(scores.precision) and scores.recall == 0.0 and scores.iou == 0.0


def test_bad_masks_are_refused():
    with pytest.raises(ValueError, match=r"predicted \(3, 3\), target \(4, 4\)"):
        mask_scores(np.zeros((3, 3), bool), np.zeros((4, 4), bool))
    with pytest.raises(TypeError, match="boolean"):
        mask_scores(np.zeros((3, 3)), np.zeros((3, 3), bool))


def test_mean_std_rule_picks_the_outlying_patch():
    saliency = np.full((8, 8), 0.1)
    saliency[:2, :2] = 1.0
    assert np.array_equal(threshold_saliency(saliency), saliency > 0.5)
    # a larger num_std can leave nothing above the threshold
    assert not threshold_saliency(saliency, num_std=10.0).any()


def test_top_fraction_rule_and_unknown_rule():
    saliency = np.arange(100, dtype=float).reshape(10, 10)
    mask = threshold_saliency(saliency, rule="top_fraction", fraction=0.05)
    assert mask.sum() == 5 and mask.ravel()[-5:].all()
    with pytest.raises(ValueError, match="Unknown threshold rule 'median'"):
        threshold_saliency(saliency, rule="median")
    with pytest.raises(ValueError, match="fraction"):
        threshold_saliency(saliency, rule="top_fraction", fraction=0.0)
