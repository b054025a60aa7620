"""Scoring a saliency map against the simulator's agent mask: threshold rule, precision, recall, IoU."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

THRESHOLD_RULES = ("mean_std", "top_fraction")


def threshold_saliency(
    saliency: np.ndarray, rule: str = "mean_std", num_std: float = 1.0, fraction: float = 0.1
) -> np.ndarray:
    """A (h, w) saliency map as a boolean mask: pixels above ``mean + num_std * std``, or the top ``fraction``."""
    saliency = np.asarray(saliency, dtype=np.float64)
    if saliency.ndim != 2:
        raise ValueError(f"Expected a (height, width) saliency map, got shape {saliency.shape}")
    if rule == "mean_std":
        return saliency > saliency.mean() + num_std * saliency.std()
    if rule == "top_fraction":
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f"fraction must be in (0, 1], got {fraction}")
        count = max(1, round(fraction * saliency.size))
        cut = np.partition(saliency.ravel(), saliency.size - count)[saliency.size - count]
        return saliency >= cut
    raise ValueError(f"Unknown threshold rule {rule!r}, expected one of {THRESHOLD_RULES}")


@dataclass(frozen=True)
class MaskScores:
    """Pixel-level agreement of a predicted mask with the true agent mask (NaN where a ratio is undefined)."""

    precision: float
    recall: float
    iou: float

    def as_dict(self) -> dict[str, float]:
        return asdict(self)


def _ratio(numerator: int, denominator: int) -> float:
    return numerator / denominator if denominator > 0 else float("nan")


def mask_scores(predicted: np.ndarray, target: np.ndarray) -> MaskScores:
    """Precision, recall and IoU of two boolean masks of one shape (NaN for a zero denominator)."""
    predicted, target = np.asarray(predicted), np.asarray(target)
    if predicted.shape != target.shape:
        raise ValueError(f"Mask shapes differ: predicted {predicted.shape}, target {target.shape}")
    if predicted.dtype != bool or target.dtype != bool:
        raise TypeError(f"Expected boolean masks, got predicted {predicted.dtype} and target {target.dtype}")
    true_positive = int(np.count_nonzero(predicted & target))
    false_positive = int(np.count_nonzero(predicted & ~target))
    false_negative = int(np.count_nonzero(~predicted & target))
    return MaskScores(
        precision=_ratio(true_positive, true_positive + false_positive),
        recall=_ratio(true_positive, true_positive + false_negative),
        iou=_ratio(true_positive, true_positive + false_positive + false_negative),
    )
