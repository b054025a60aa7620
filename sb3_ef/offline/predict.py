"""Open-loop predictions of a pretrained model for dataset actions or the paper's figure-eight, as images and video."""

from __future__ import annotations

import os

import numpy as np
import torch as th

from sb3_ef.analysis.prediction import (
    eval_mode,
    figure_eight_actions,
    frame_grid,
    save_image,
    save_video,
    to_uint8_frames,
)
from sb3_ef.offline.episodes import Episode
from sb3_ef.offline.model import OfflineEF

ACTION_SOURCES = ("dataset", "figure8")
ROW_LABELS = ("context", "prediction", "truth")
LABEL_WIDTH = 64


def labelled_grid(rows: list[np.ndarray], labels: list[str], spacing: int = 2) -> np.ndarray:
    """``frame_grid(rows)`` with a column on the left naming each row (white text on black)."""
    from PIL import Image, ImageDraw

    grid = frame_grid(rows, spacing)
    height = rows[0].shape[1]
    image = Image.new("RGB", (LABEL_WIDTH + grid.shape[1], grid.shape[0]))
    image.paste(Image.fromarray(grid), (LABEL_WIDTH, 0))
    draw = ImageDraw.Draw(image)
    for index, label in enumerate(labels):
        top = index * (height + spacing) + height // 2
        draw.text((2, top), label, fill=(255, 255, 255), anchor="lm")
    return np.asarray(image)


@th.no_grad()
def predict_frames(model: OfflineEF, context: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """The uint8 (T, H, W, 3) frames after each of ``actions`` from ``context`` frames; T may exceed the horizon."""
    config = model.config
    context = np.asarray(context)
    expected = (config.context, *config.frame_shape)
    if context.shape != expected or context.dtype != np.uint8:
        raise ValueError(f"Expected uint8 context frames of shape {expected}, got {context.dtype} {context.shape}")
    actions = np.asarray(actions, dtype=np.float32)
    if actions.ndim != 2 or actions.shape[1] != config.action_dim or len(actions) < 1:
        raise ValueError(f"Expected actions of shape (steps, {config.action_dim}), got {actions.shape}")
    device = next(model.parameters()).device
    observation = th.as_tensor(context.reshape(1, -1, *context.shape[2:])).to(device)
    with eval_mode(model):
        h, skip = model.features(observation)
        frames = model.ef.predict(h, th.as_tensor(actions).unsqueeze(0).to(device), skip)
    return to_uint8_frames(frames[0])


def predict_episode(
    model: OfflineEF,
    episode: Episode,
    out_dir: str | os.PathLike,
    start: int | None = None,
    actions: str = "dataset",
    steps: int | None = None,
    video: str = "gif",
) -> dict[str, str]:
    """Predict from the context ending at frame ``start`` and write ``prediction.png`` and ``.gif`` / ``.mp4``.

    :param actions: ``"dataset"`` (the episode's own, true frames shown) or ``"figure8"`` (the paper's probe).
    :param steps: frames to predict (default: the horizon; with dataset actions at most to the episode's end).
    """
    if actions not in ACTION_SOURCES:
        raise ValueError(f"actions must be one of {ACTION_SOURCES}, got {actions!r}")
    context = model.config.context
    start = context - 1 if start is None else start
    steps = model.config.horizon if steps is None else steps
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be a positive number of frames to predict (--steps), got {steps!r}")
    if not context - 1 <= start < episode.steps:
        raise ValueError(f"start must lie in [{context - 1}, {episode.steps - 1}] for {episode.source}, got {start}")
    if actions == "dataset":
        steps = min(steps, episode.steps - start)
        sequence = episode.actions[start : start + steps]
        truth = episode.frames[start + 1 : start + steps + 1].transpose(0, 2, 3, 1)
    else:
        sequence, truth = figure_eight_actions(steps, model.config.action_dim), None
    context_frames = episode.frames[start - context + 1 : start + 1]
    predicted = predict_frames(model, context_frames, sequence)
    os.makedirs(out_dir, exist_ok=True)
    rows = [context_frames.transpose(0, 2, 3, 1), predicted] + ([truth] if truth is not None else [])
    grid = labelled_grid(rows, list(ROW_LABELS[: len(rows)]))
    return {
        "grid": save_image(os.path.join(out_dir, "prediction.png"), grid),
        "video": save_video(os.path.join(out_dir, f"prediction.{video}"), predicted, truth),
    }
