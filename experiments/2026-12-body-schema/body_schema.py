"""Does EF treat an object as part of the agent? Two measures per image region (robot, tool, door, distractor).

- **Saliency share**: the part of an h_a saliency map's total mass (``sb3_ef.analysis.saliency``) that lies on a
  region's pixels. A region that h_a does not draw gets about its area share or less; one that h_a draws gets a
  multiple of it. ``enrichment`` = share / area share (1 = no preference).
- **Region error against the copy baseline**: the squared error per pixel (values in [0, 1], mean over the colour
  channels) of the predicted frame t + k over a region's pixels, and the same for the newest context frame t copied
  forward. The region at step k is the union of its masks at t and at t + k (where the object is or was: the pixels
  a static copy gets wrong). Errors are summed over windows and k, then divided by the summed pixel count, so a
  window weighs by its region's size. ``ratio`` = model / copy: below 1 the model predicts the region's motion,
  about 1 or above it does not. A region that did not move has copy error 0 and no meaningful ratio.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from sb3_ef.analysis.prediction import eval_mode, frame_grid, module_device, to_uint8_frames
from sb3_ef.analysis.saliency import Saliency, decoder_saliency, saliency_overlay


def saliency_share(saliency: np.ndarray, mask: np.ndarray) -> float:
    """Share of a non-negative (h, w) saliency map's total on the pixels of the bool (h, w) ``mask``; NaN for an
    all-zero map."""
    saliency, mask = np.asarray(saliency, dtype=np.float64), np.asarray(mask)
    if saliency.shape != mask.shape or saliency.ndim != 2:
        raise ValueError(f"Expected a (h, w) map and a mask of the same shape, got {saliency.shape} and {mask.shape}")
    if mask.dtype != bool:
        raise TypeError(f"Expected a boolean mask, got dtype {mask.dtype}")
    if (saliency < 0).any():
        raise ValueError("Saliency maps are gradient norms: expected non-negative values")
    total = saliency.sum()
    return float(saliency[mask].sum() / total) if total > 0 else float("nan")


def saliency_shares(maps: np.ndarray, masks: Mapping[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Per region: mean ``share`` of ``maps`` (N, h, w) on ``masks[name]`` (N, h, w) over the N maps, mean area
    ``fraction`` of the region, and ``enrichment`` = share / fraction (NaN for an empty region)."""
    maps = np.asarray(maps)
    scores = {}
    for name, mask in masks.items():
        mask = np.asarray(mask)
        if mask.shape != maps.shape:
            raise ValueError(f"Region {name!r}: masks {mask.shape} do not match the saliency maps {maps.shape}")
        share = float(np.nanmean([saliency_share(m, r) for m, r in zip(maps, mask, strict=True)]))
        fraction = float(mask.mean())
        scores[name] = {"share": share, "fraction": fraction, "enrichment": share / fraction if fraction else np.nan}
    return scores


class RegionErrors:
    """Accumulates model and copy-baseline squared errors over regions, batch by batch (see the module doc)."""

    def __init__(self) -> None:
        self.sums: dict[str, np.ndarray] = {}

    def add(self, predicted: np.ndarray, truth: np.ndarray, last: np.ndarray, masks: Mapping[str, np.ndarray]) -> None:
        """One batch of windows.

        :param predicted: (N, H, 3, h, w) predicted frames t + 1..t + H in [0, 1].
        :param truth: (N, H, 3, h, w) true frames in [0, 1].
        :param last: (N, 3, h, w) the newest context frame t in [0, 1].
        :param masks: region name -> bool (N, H + 1, h, w): index 0 the mask at t, index k the mask at t + k.
        """
        predicted, truth, last = (np.asarray(a, dtype=np.float64) for a in (predicted, truth, last))
        if predicted.shape != truth.shape or predicted.ndim != 5 or last.shape != truth.shape[:1] + truth.shape[2:]:
            raise ValueError(
                f"Expected predicted and truth (N, H, 3, h, w) and last (N, 3, h, w), got {predicted.shape}, "
                f"{truth.shape} and {last.shape}"
            )
        model_error = ((predicted - truth) ** 2).mean(axis=2)  # (N, H, h, w)
        copy_error = ((last[:, None] - truth) ** 2).mean(axis=2)
        count, horizon = truth.shape[:2]
        for name, mask in masks.items():
            mask = np.asarray(mask)
            if mask.shape != (count, horizon + 1, *truth.shape[3:]) or mask.dtype != bool:
                raise ValueError(
                    f"Region {name!r}: expected bool masks of shape {(count, horizon + 1, *truth.shape[3:])}, "
                    f"got {mask.dtype} {mask.shape}"
                )
            region = mask[:, 1:] | mask[:, :1]
            sums = self.sums.setdefault(name, np.zeros((3, horizon)))
            sums += [(model_error * region).sum(axis=(0, 2, 3)), (copy_error * region).sum(axis=(0, 2, 3)),
                     region.sum(axis=(0, 2, 3))]  # fmt: skip

    def scores(self) -> dict[str, dict[str, float | list[float]]]:
        """Per region: ``model_mse``, ``copy_mse``, ``ratio`` (over all k), ``ratio_per_k`` and ``pixels`` (mean
        region pixels per window and k, relative to the frame: see ``fraction``)."""
        scores = {}
        for name, (model, copy, pixels) in self.sums.items():
            model_mse = model.sum() / pixels.sum() if pixels.sum() else np.nan
            copy_mse = copy.sum() / pixels.sum() if pixels.sum() else np.nan
            with np.errstate(divide="ignore", invalid="ignore"):
                per_k = np.where(copy > 0, model / np.where(copy > 0, copy, 1), np.nan)
            scores[name] = {
                "model_mse": float(model_mse),
                "copy_mse": float(copy_mse),
                "ratio": float(model_mse / copy_mse) if copy_mse > 0 else float("nan"),
                "ratio_per_k": per_k.tolist(),
                "pixels": float(pixels.sum()),
            }
        return scores


# --- Windows of scripted episodes, model predictions and saliency --------------------------------------------------

ATTACHMENT_RULES = (None, "context", "window")


@dataclass(frozen=True)
class RegionWindows:
    """Evaluation windows: ``observations`` uint8 (N, 3 * context, h, w) oldest first, ``actions`` (N, H, A),
    ``frames`` uint8 (N, H, 3, h, w) for t + 1..t + H, ``masks`` region -> bool (N, H + 1, h, w) (index 0 = t),
    ``motion`` (N,) how far the object moved from t to t + H (metres; NaN when episodes carry no positions)."""

    observations: np.ndarray
    actions: np.ndarray
    frames: np.ndarray
    masks: dict[str, np.ndarray]
    motion: np.ndarray

    def __len__(self) -> int:
        return len(self.observations)

    def subset(self, indices: np.ndarray | slice) -> RegionWindows:
        return RegionWindows(
            self.observations[indices],
            self.actions[indices],
            self.frames[indices],
            {name: mask[indices] for name, mask in self.masks.items()},
            self.motion[indices],
        )


def cut_region_windows(
    episodes: list[Any], context: int, horizon: int, stride: int = 1, require_attached: str | None = None
) -> RegionWindows:
    """Windows (last context frame t, every ``stride``-th valid t) of episodes with ``frames``, ``actions``,
    ``masks`` (name -> (T + 1, h, w)), ``attached`` (T + 1,) and ``object`` positions (T + 1, 3) such as
    :class:`scripted.ScriptedEpisode` (``scripted.py`` beside this file).

    :param require_attached: None (all windows), ``"context"`` (the object is attached at t) or ``"window"``
        (attached in every frame of the window, context and targets).
    """
    if require_attached not in ATTACHMENT_RULES:
        raise ValueError(f"require_attached must be one of {ATTACHMENT_RULES}, got {require_attached!r}")
    observations, actions, frames, motion = [], [], [], []
    masks: dict[str, list[np.ndarray]] = {}
    for episode in episodes:
        if not episode.masks:
            raise ValueError("Evaluation windows need episodes recorded with masks")
        for t in range(context - 1, len(episode.actions) - horizon + 1, stride):
            if require_attached == "context" and not episode.attached[t]:
                continue
            if require_attached == "window" and not episode.attached[t - context + 1 : t + horizon + 1].all():
                continue
            observations.append(episode.frames[t - context + 1 : t + 1].reshape(-1, *episode.frames.shape[2:]))
            actions.append(episode.actions[t : t + horizon])
            frames.append(episode.frames[t + 1 : t + horizon + 1])
            motion.append(np.linalg.norm(episode.object[t + horizon] - episode.object[t]))
            for name, mask in episode.masks.items():
                masks.setdefault(name, []).append(mask[t : t + horizon + 1])
    if not observations:
        raise ValueError(
            f"No window of context {context} + horizon {horizon} with require_attached={require_attached!r}"
        )
    return RegionWindows(
        np.stack(observations),
        np.stack(actions),
        np.stack(frames),
        {name: np.stack(mask) for name, mask in masks.items()},
        np.array(motion),
    )


@th.no_grad()
def predict_region_windows(model: Any, windows: RegionWindows, batch_size: int = 32) -> np.ndarray:
    """Open-loop predictions (N, H, 3, h, w) in [0, 1] of a model with ``features(obs) -> (h, skip)`` and ``ef``
    (:class:`~sb3_ef.offline.model.OfflineEF`)."""
    device = module_device(model)
    outputs = []
    with eval_mode(model):
        for start in range(0, len(windows), batch_size):
            observations = th.as_tensor(windows.observations[start : start + batch_size]).to(device)
            actions = th.as_tensor(windows.actions[start : start + batch_size]).float().to(device)
            h, skip = model.features(observations)
            outputs.append(model.ef.predict(h, actions, skip).cpu().numpy())
    return np.concatenate(outputs)


def region_saliency(model: Any, windows: RegionWindows, index: int, k: int) -> Saliency:
    """h_a / h_s saliency of the frame predicted ``k`` steps after window ``index`` (U-Net skips passed on)."""
    device = module_device(model)
    with eval_mode(model), th.no_grad():
        h, skip = model.features(th.as_tensor(windows.observations[index : index + 1]).to(device))
        h_scene, h_agent = model.ef.split(h)
        actions = th.as_tensor(windows.actions[index : index + 1, :k]).float().to(device)
        rolled = model.ef.rollout(h_agent, actions)[:, -1]
    return decoder_saliency(model.ef, h_scene, rolled, skip=skip)


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Bool (..., h, w) mask grown by ``radius`` pixels in every direction (a square neighbourhood)."""
    if radius < 0:
        raise ValueError(f"radius must be >= 0, got {radius}")
    padding = [(0, 0)] * (mask.ndim - 2) + [(radius, radius)] * 2
    padded = np.pad(np.asarray(mask, bool), padding)
    windows = np.lib.stride_tricks.sliding_window_view(padded, (2 * radius + 1, 2 * radius + 1), axis=(-2, -1))
    return np.asarray(windows.any(axis=(-2, -1)))


def evaluate_regions(
    model: Any, windows: RegionWindows, saliency_windows: int = 16, seed: int = 0, band: int = 4
) -> dict[str, dict[str, Any]]:
    """Region errors against the copy baseline on every window (plus the region ``"frame"``, all pixels) and h_a
    saliency shares on ``saliency_windows`` windows drawn with ``seed``, k cycling through 1..H, plus two control
    regions for the saliency: ``"near_agent"``, the pixels within ``band`` pixels of the agent that belong to no
    named region (what patch-level saliency of the agent spills onto), and ``"rest"``, the pixels of no named
    region."""
    errors = RegionErrors()
    predicted = predict_region_windows(model, windows)
    truth = windows.frames / 255.0
    last = windows.observations[:, -3:] / 255.0
    every_pixel = np.ones((len(truth), truth.shape[1] + 1, *truth.shape[3:]), bool)
    errors.add(predicted, truth, last, {**windows.masks, "frame": every_pixel})
    scores: dict[str, dict[str, Any]] = {name: dict(value) for name, value in errors.scores().items()}
    horizon = windows.actions.shape[1]
    rng = np.random.default_rng(seed)
    chosen = rng.choice(len(windows), size=min(saliency_windows, len(windows)), replace=False)
    if len(chosen):
        maps = []
        region_masks: dict[str, list[np.ndarray]] = {name: [] for name in windows.masks}
        for number, index in enumerate(chosen):
            k = 1 + number % horizon
            maps.append(region_saliency(model, windows, int(index), k).agent)
            for name, mask in windows.masks.items():
                region_masks[name].append(mask[index, k])
        stacked = {name: np.stack(masks) for name, masks in region_masks.items()}
        named = np.logical_or.reduce(list(stacked.values()))
        if "agent" in stacked:
            stacked["near_agent"] = dilate(stacked["agent"], band) & ~named
        stacked["rest"] = ~named
        for name, values in saliency_shares(np.stack(maps), stacked).items():
            scores.setdefault(name, {}).update({f"saliency_{key}": value for key, value in values.items()})
    scores["windows"] = {
        "count": len(windows),
        "saliency": len(chosen),
        "object_motion": float(windows.motion.mean()),
        "moving_fraction": float((windows.motion > 0.01).mean()),
    }
    return scores


# --- Figures -------------------------------------------------------------------------------------------------------

#: Tints of the region masks in figures (RGB).
MASK_COLOURS = {"agent": (0, 90, 255)}
OBJECT_COLOUR = (0, 220, 0)
#: Colour of the h_a saliency overlay (yellow: the Sawyer robot is red).
SALIENCY_COLOUR = (255, 255, 0)


def tint(frame: np.ndarray, mask: np.ndarray, colour: tuple[int, int, int], alpha: float = 0.5) -> np.ndarray:
    """A uint8 (h, w, 3) frame with ``colour`` blended in at weight ``alpha`` on the pixels of ``mask``."""
    out = frame.astype(np.float64)
    out[mask] = (1 - alpha) * out[mask] + alpha * np.asarray(colour, dtype=np.float64)
    return out.round().astype(np.uint8)


def window_figure(model: Any, windows: RegionWindows, index: int = 0) -> np.ndarray:
    """One window as a uint8 image with four rows: the context frames; the predicted frames t + 1..t + H; the same
    with the h_a saliency of each in yellow; the true frames with the agent's mask in blue and every other region's
    in green."""
    predicted = to_uint8_frames(th.as_tensor(predict_region_windows(model, windows.subset(slice(index, index + 1)))[0]))
    horizon = len(predicted)
    context = windows.observations[index].reshape(-1, 3, *windows.observations.shape[2:]).transpose(0, 2, 3, 1)
    salient = np.stack(
        [
            saliency_overlay(frame, region_saliency(model, windows, index, k).agent, color=SALIENCY_COLOUR)
            for k, frame in enumerate(predicted, 1)
        ]
    )
    truth = windows.frames[index].transpose(0, 2, 3, 1)
    tinted = []
    for k in range(horizon):
        frame = truth[k]
        for name, mask in windows.masks.items():
            frame = tint(frame, mask[index, k + 1], MASK_COLOURS.get(name, OBJECT_COLOUR))
        tinted.append(frame)
    return frame_grid([context, predicted, salient, np.stack(tinted)])
