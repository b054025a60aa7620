"""Held-out scores of an offline EF model next to the copy-the-last-frame baseline (see docs/offline.md)."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from sb3_ef.analysis.masks import mask_scores, threshold_saliency
from sb3_ef.analysis.prediction import eval_mode
from sb3_ef.analysis.saliency import Saliency, decoder_saliency
from sb3_ef.offline.episodes import Episode
from sb3_ef.offline.model import OfflineEF
from sb3_ef.offline.progress import make_progress_bar
from sb3_ef.offline.windows import Windows, cut_windows, window_starts


def evaluation_picks(episodes: list[Episode], context: int, horizon: int, stride: int) -> list[tuple[int, int]]:
    """Every ``stride``-th window of every episode."""
    return [
        (index, int(t))
        for index, episode in enumerate(episodes)
        for t in window_starts(episode, context, horizon)[::stride]
    ]


@th.no_grad()
def predict_windows(model: OfflineEF, windows: Windows) -> th.Tensor:
    """Open-loop predictions (B, H, 3, h, w) in [0, 1] for each window's actions."""
    with eval_mode(model):
        h, skip = model.features(windows.observations)
        return model.ef.predict(h, windows.actions.float(), skip)


def evaluate(
    model: OfflineEF,
    episodes: list[Episode],
    stride: int = 5,
    batch_size: int = 64,
    saliency_windows: int = 32,
    seed: int = 0,
    progress: bool = False,
) -> dict[str, float | list[float]]:
    """Scores on held-out ``episodes`` (named in docs/offline.md's "Held-out scores"); ``progress`` shows a bar."""
    config = model.config
    picks = evaluation_picks(episodes, config.context, config.horizon, stride)
    if not picks:
        raise ValueError(f"No held-out episode has context + horizon = {config.context + config.horizon} frames")
    device = next(model.parameters()).device
    horizon = config.horizon
    sums = {name: np.zeros(horizon) for name in ("frame", "copy_frame", "agent", "copy_agent", "agent_pixels")}
    with_masks = all(episodes[index].masks is not None for index, _ in picks)
    total = -(-len(picks) // batch_size) + (min(saliency_windows, len(picks)) if with_masks else 0)
    bar = make_progress_bar(total, "held-out evaluation", "step", progress)
    for start in range(0, len(picks), batch_size):
        windows = cut_windows(episodes, picks[start : start + batch_size], config.context, horizon, device)
        predicted = predict_windows(model, windows)
        truth = windows.frames.float() / 255.0
        last = windows.observations[:, -3:].float().unsqueeze(1) / 255.0
        model_error = (predicted - truth).pow(2).mean(dim=2)  # (B, H, h, w), mean over colours
        copy_error = (last - truth).pow(2).mean(dim=2)
        sums["frame"] += model_error.mean(dim=(2, 3)).sum(0).cpu().numpy()
        sums["copy_frame"] += copy_error.mean(dim=(2, 3)).sum(0).cpu().numpy()
        if with_masks:
            agent = windows.masks[:, 1:] | windows.masks[:, :1]  # type: ignore[index]
            sums["agent"] += (model_error * agent).sum(dim=(0, 2, 3)).cpu().numpy()
            sums["copy_agent"] += (copy_error * agent).sum(dim=(0, 2, 3)).cpu().numpy()
            sums["agent_pixels"] += agent.sum(dim=(0, 2, 3)).cpu().numpy()
        bar.update(1)
    scores: dict[str, float | list[float]] = {"windows": float(len(picks))}
    _add_errors(scores, "frame", sums["frame"] / len(picks), sums["copy_frame"] / len(picks))
    if with_masks:
        pixels = np.maximum(sums["agent_pixels"], 1)
        _add_errors(scores, "agent", sums["agent"] / pixels, sums["copy_agent"] / pixels)
        scores.update(saliency_scores(model, episodes, picks, saliency_windows, seed, bar))
    bar.close()
    return scores


def _add_errors(scores: dict, name: str, model_error: np.ndarray, copy_error: np.ndarray) -> None:
    scores[f"{name}_mse_per_k"] = model_error.tolist()
    scores[f"copy_{name}_mse_per_k"] = copy_error.tolist()
    scores[f"{name}_mse"] = float(model_error.mean())
    scores[f"copy_{name}_mse"] = float(copy_error.mean())
    scores[f"{name}_ratio"] = float(model_error.mean() / max(copy_error.mean(), 1e-12))


def window_saliency(model: OfflineEF, windows: Windows, index: int, k: int) -> Saliency:
    """h_a / h_s saliency (``sb3_ef.analysis.saliency``) of the frame predicted k steps after window ``index``."""
    with eval_mode(model), th.no_grad():
        h, skip = model.features(windows.observations[index : index + 1])
        h_scene, h_agent = model.ef.split(h)
        rolled = model.ef.rollout(h_agent, windows.actions[index : index + 1, :k].float())[:, -1]
    return decoder_saliency(model.ef, h_scene, rolled, skip=skip)


def saliency_scores(
    model: OfflineEF, episodes: list[Episode], picks: list[tuple[int, int]], count: int, seed: int, bar: Any
) -> dict[str, float]:
    """Mean precision / recall of the h_a saliency of frame t + k against its agent mask, over ``count`` windows."""
    config = model.config
    rng = np.random.default_rng(seed)
    chosen = [picks[i] for i in rng.choice(len(picks), size=min(count, len(picks)), replace=False)]
    windows = cut_windows(episodes, chosen, config.context, config.horizon, next(model.parameters()).device)
    precision, recall, chance = [], [], []
    for i, k in enumerate(rng.integers(1, config.horizon + 1, len(chosen))):
        truth = windows.masks[i, k].cpu().numpy()  # type: ignore[index]
        bar.update(1)
        if not truth.any():
            continue
        scores = mask_scores(threshold_saliency(window_saliency(model, windows, i, int(k)).agent), truth)
        precision.append(scores.precision)
        recall.append(scores.recall)
        chance.append(truth.mean())
    if not precision:
        return {}
    mean_precision, mean_chance = float(np.nanmean(precision)), float(np.mean(chance))
    return {
        "saliency_precision": mean_precision,
        "saliency_recall": float(np.nanmean(recall)),
        "saliency_chance": mean_chance,
        "saliency_precision_over_chance": mean_precision / mean_chance,
    }
