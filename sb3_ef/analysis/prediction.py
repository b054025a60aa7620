"""Open-loop Ego-Foresight predictions from one observation and an action sequence, and their writers."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import Any, Protocol

import numpy as np
import torch as th
from torch import nn

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.files import atomic_path
from sb3_ef.ef import EgoForesight


class ForesightModel(Protocol):
    """What DrQv2EF and TDMPC2EF expose for analysis (docs/architecture.md, "Models expose EF the same way")."""

    ef: Any
    frame_shape: tuple[int, int, int]

    def encode(self, observations: th.Tensor) -> th.Tensor: ...


Encoder = Callable[[th.Tensor], th.Tensor]


def resolve_foresight(
    model: ForesightModel | None = None, encoder: Encoder | None = None, ef: EgoForesight | None = None
) -> tuple[Encoder, EgoForesight]:
    """``(encode, ef)`` of a model following the contract, or of an explicit encoder and EF module."""
    if model is not None:
        if encoder is not None or ef is not None:
            raise ValueError("Pass either a model or encoder + ef, not both")
        if getattr(model, "ef", None) is None:
            raise ValueError(f"{type(model).__name__} has no Ego-Foresight module (model.ef is None): EF is off")
        encoder, ef = model.encode, model.ef
    elif encoder is None or ef is None:
        raise ValueError("Need a model with .ef and .encode, or both encoder and ef")
    if getattr(ef, "skip_channels", 0):
        raise ValueError(
            f"Analysis needs an EgoForesight without U-Net skips (skip_channels=0), got {ef.skip_channels}: "
            "model.encode returns features only, not the skip feature maps"
        )
    return encoder, ef


def module_device(module: nn.Module) -> th.device:
    """The device of a module's first parameter (CPU for a parameter-free module)."""
    parameter = next(module.parameters(), None)
    return parameter.device if parameter is not None else th.device("cpu")


@contextlib.contextmanager
def eval_mode(*modules: Any) -> Iterator[None]:
    """The given nn.Modules in eval mode (BatchNorm statistics, no dropout) within the block."""
    torch_modules = [module for module in modules if isinstance(module, nn.Module)]
    flags = [module.training for module in torch_modules]
    for module in torch_modules:
        module.eval()
    try:
        yield
    finally:
        for module, flag in zip(torch_modules, flags, strict=True):
            module.train(flag)


def as_observation_batch(observation: np.ndarray | th.Tensor, device: th.device) -> th.Tensor:
    """A single stacked uint8 observation (C*k, h, w) as a (1, C*k, h, w) tensor on ``device``."""
    tensor = th.as_tensor(np.asarray(observation) if not isinstance(observation, th.Tensor) else observation)
    if tensor.dim() != 3 or tensor.shape[0] % FRAME_CHANNELS != 0 or tensor.dtype != th.uint8:
        raise ValueError(
            "Expected one stacked uint8 observation of shape (3 * frame_stack, height, width), "
            f"got shape {tuple(tensor.shape)} and dtype {tensor.dtype}"
        )
    return tensor.unsqueeze(0).to(device)


def action_batch(actions: np.ndarray | th.Tensor, ef: EgoForesight, device: th.device) -> th.Tensor:
    """(T, action_dim) actions, checked against ``ef``, as a float (1, T, action_dim) batch on ``device``."""
    tensor = actions if isinstance(actions, th.Tensor) else th.as_tensor(np.asarray(actions, dtype=np.float32))
    if tensor.dim() != 2 or tensor.shape[0] < 1:
        raise ValueError(f"Expected actions of shape (steps, action_dim), got {tuple(tensor.shape)}")
    expected_dim = getattr(ef, "action_dim", tensor.shape[1])
    if tensor.shape[1] != expected_dim:
        raise ValueError(f"Expected actions with {expected_dim} dimensions, got {tensor.shape[1]}")
    return tensor.float().unsqueeze(0).to(device)


def context_frames(observation: np.ndarray) -> np.ndarray:
    """The frames of a channels-first stacked observation, oldest first, as uint8 (k, h, w, 3)."""
    observation = np.asarray(observation)
    if observation.ndim != 3 or observation.shape[0] % FRAME_CHANNELS != 0:
        raise ValueError(f"Expected a (3 * frame_stack, height, width) observation, got shape {observation.shape}")
    stacked = observation.reshape(-1, FRAME_CHANNELS, *observation.shape[1:])
    return np.ascontiguousarray(stacked.transpose(0, 2, 3, 1))


def to_uint8_frames(frames: th.Tensor) -> np.ndarray:
    """(..., 3, h, w) floats in [0, 1] -> (..., h, w, 3) uint8."""
    array = (frames.detach().clamp(0, 1) * 255).round().to(th.uint8).cpu().numpy()
    return np.moveaxis(array, -3, -1)


def figure_eight_actions(steps: int, action_dim: int, period: int = 40) -> np.ndarray:
    """A probe, float32 (steps, action_dim): a figure-eight velocity ``cos(w t), cos(2 w t)`` on two components."""
    if action_dim < 1:
        raise ValueError(f"figure_eight_actions needs an action space with at least 1 dimension, got {action_dim}")
    if steps < 1 or period < 2:
        raise ValueError(f"Need steps >= 1 and period >= 2, got steps={steps}, period={period}")
    phase = 2 * np.pi * np.arange(steps) / period
    actions = np.zeros((steps, action_dim), dtype=np.float32)
    actions[:, 0] = np.cos(phase)
    if action_dim > 1:
        actions[:, 1] = np.cos(2 * phase)
    return actions


@th.no_grad()
def predict_open_loop(
    observation: np.ndarray | th.Tensor,
    actions: np.ndarray | th.Tensor,
    model: ForesightModel | None = None,
    encoder: Encoder | None = None,
    ef: EgoForesight | None = None,
) -> np.ndarray:
    """The T uint8 (T, h, w, 3) frames EF predicts open loop after ``actions`` from one stacked observation."""
    encode, foresight = resolve_foresight(model, encoder, ef)
    device = module_device(foresight)
    with eval_mode(foresight, encoder):
        features = encode(as_observation_batch(observation, device))
        frames = foresight.predict(features, action_batch(actions, foresight, device))
    return to_uint8_frames(frames[0])


def frame_grid(rows: list[np.ndarray], spacing: int = 2) -> np.ndarray:
    """Lay out rows of uint8 (n, h, w, 3) frames in one image; short rows are padded with black."""
    if not rows:
        raise ValueError("frame_grid needs at least one row of frames")
    height, width = rows[0].shape[1:3]
    for row in rows:
        if row.ndim != 4 or row.shape[1:] != (height, width, 3):
            raise ValueError(f"Expected rows of (n, {height}, {width}, 3) frames, got {row.shape}")
    columns = max(len(row) for row in rows)
    grid = np.zeros(
        (len(rows) * (height + spacing) - spacing, columns * (width + spacing) - spacing, 3), dtype=np.uint8
    )
    for row_index, row in enumerate(rows):
        for column_index, frame in enumerate(row):
            top, left = row_index * (height + spacing), column_index * (width + spacing)
            grid[top : top + height, left : left + width] = frame
    return grid


def save_image(path: str | os.PathLike, image: np.ndarray) -> str:
    """Write a uint8 (h, w, 3) image (PNG, or any format Pillow infers from the suffix); return the path."""
    from PIL import Image

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with atomic_path(path) as temporary:
        Image.fromarray(image).save(temporary)
    return os.fspath(path)


def save_prediction_grid(
    path: str | os.PathLike, context: np.ndarray, predicted: np.ndarray, true: np.ndarray | None = None
) -> str:
    """PNG with one row each: the context frames (k, h, w, 3), the predicted frames, and the true frames if given."""
    rows = [context, predicted] if true is None else [context, predicted, true]
    return save_image(path, frame_grid(rows))


def save_video(path: str | os.PathLike, predicted: np.ndarray, true: np.ndarray | None = None, fps: int = 10) -> str:
    """GIF or MP4 (by suffix; MP4 needs ``imageio-ffmpeg``) of the predicted frames, beside the true ones if given."""
    frames = predicted if true is None else np.concatenate([predicted, true[: len(predicted)]], axis=2)
    import imageio.v2 as imageio

    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    suffix = os.path.splitext(os.fspath(path))[1].lower()
    if suffix not in (".gif", ".mp4"):
        raise ValueError(f"Expected a .gif or .mp4 path, got {os.fspath(path)!r}")
    if suffix == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError as error:
            raise ImportError("Writing MP4 needs imageio-ffmpeg: pip install imageio-ffmpeg (or use a .gif)") from error
    options = {"duration": 1000 / fps, "loop": 0} if suffix == ".gif" else {"fps": fps, "macro_block_size": 1}
    with atomic_path(path) as temporary:
        imageio.mimsave(os.fspath(temporary), list(frames), **options)
    return os.fspath(path)
