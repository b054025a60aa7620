"""Feature statistics of a LeRobot dataset in LeRobot's form: exact per episode, aggregated as LeRobot does."""

from __future__ import annotations

from typing import Any

import numpy as np

QUANTILES = {"q01": 0.01, "q10": 0.10, "q50": 0.50, "q90": 0.90, "q99": 0.99}
#: Per-feature statistics: ``{statistic: array}``; a dataset's or episode's: ``{feature: that}``.
Stats = dict[str, dict[str, np.ndarray]]


def image_stats(frames: np.ndarray) -> dict[str, np.ndarray]:
    """Per-channel statistics of uint8 frames (N, 3, H, W), scaled to [0, 1], each shaped (3, 1, 1)."""
    counts = np.stack([np.bincount(frames[:, c].ravel(), minlength=256) for c in range(frames.shape[1])])
    values = np.arange(256, dtype=np.float64)
    total = counts.sum(axis=1)
    mean = counts @ values / total
    variance = (counts * (values[None] - mean[:, None]) ** 2).sum(axis=1) / total
    present = counts > 0
    stats = {
        "min": present.argmax(axis=1).astype(np.float64),
        "max": 255 - present[:, ::-1].argmax(axis=1).astype(np.float64),
        "mean": mean,
        "std": np.sqrt(variance),
        **{name: np.array([_histogram_quantile(row, q) for row in counts]) for name, q in QUANTILES.items()},
    }
    shaped = {name: (value / 255.0).reshape(-1, 1, 1) for name, value in stats.items()}
    return {**shaped, "count": np.array([len(frames)])}


def _histogram_quantile(counts: np.ndarray, q: float) -> float:
    """The ``q`` quantile of the integers with these counts, interpolated linearly as ``np.quantile`` does."""
    cumulative = np.cumsum(counts)
    position = q * (cumulative[-1] - 1)
    below = int(np.floor(position))
    low = np.searchsorted(cumulative, below, side="right")
    high = np.searchsorted(cumulative, below + 1, side="right") if below + 1 < cumulative[-1] else low
    return float(low + (position - below) * (high - low))


def vector_stats(values: np.ndarray) -> dict[str, np.ndarray]:
    """Per-component statistics of (N, d) values (a scalar column is (N, 1): statistics shaped (1,))."""
    values = np.asarray(values, dtype=np.float64).reshape(len(values), -1)
    stats = {
        "min": values.min(axis=0),
        "max": values.max(axis=0),
        "mean": values.mean(axis=0),
        "std": values.std(axis=0),
        **{name: np.quantile(values, q, axis=0) for name, q in QUANTILES.items()},
    }
    return {**stats, "count": np.array([len(values)])}


def aggregate(episodes: list[Stats]) -> Stats:
    """The dataset's statistics from its episodes' (see the module docstring)."""
    result: Stats = {}
    for feature in episodes[0]:
        parts = [episode[feature] for episode in episodes]
        counts = np.array([part["count"][0] for part in parts], dtype=np.float64)
        weights = (counts / counts.sum()).reshape(-1, *[1] * np.ndim(parts[0]["mean"]))
        means = np.stack([part["mean"] for part in parts])
        mean = (weights * means).sum(axis=0)
        variance = (weights * (np.stack([part["std"] for part in parts]) ** 2 + (means - mean) ** 2)).sum(axis=0)
        result[feature] = {
            "min": np.min([part["min"] for part in parts], axis=0),
            "max": np.max([part["max"] for part in parts], axis=0),
            "mean": mean,
            "std": np.sqrt(variance),
            "count": np.array([int(counts.sum())]),
        }
        for name, q in QUANTILES.items():
            envelope = np.min if q <= 0.5 else np.max
            result[feature][name] = envelope([part[name] for part in parts], axis=0)
    return result


def to_columns(stats: Stats) -> dict[str, Any]:
    """Episode statistics as episode-table columns ``stats/<feature>/<statistic>`` of nested lists."""
    return {
        f"stats/{feature}/{name}": value.tolist() for feature, named in stats.items() for name, value in named.items()
    }


def from_columns(row: dict[str, Any]) -> Stats:
    """The episode statistics of an episode-table row (the inverse of :func:`to_columns`)."""
    stats: Stats = {}
    for column, value in row.items():
        if column.startswith("stats/"):
            feature, name = column[len("stats/") :].rsplit("/", 1)
            stats.setdefault(feature, {})[name] = np.asarray(value)
    return stats


def to_json(stats: Stats) -> dict[str, dict[str, Any]]:
    """``meta/stats.json``'s content: every statistic as a (nested) list."""
    return {feature: {name: value.tolist() for name, value in named.items()} for feature, named in stats.items()}
