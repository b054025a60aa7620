"""Open-loop Ego-Foresight predictions from one observation and an action sequence, and their writers."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator
from typing import Any, NamedTuple, Protocol

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.preprocessing import get_action_dim
from torch import nn

from sb3_ef.common.buffers.rollout_windows import encode_actions
from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.files import atomic_path
from sb3_ef.ef import EgoForesight


class ForesightModel(Protocol):
    """What DrQv2EF and TDMPC2EF expose for analysis (docs/architecture.md, "Models expose EF the same way")."""

    ef: Any
    frame_shape: tuple[int, int, int]
    action_space: spaces.Space

    def encode(self, observations: th.Tensor) -> th.Tensor: ...


Encoder = Callable[[th.Tensor], th.Tensor]


class Foresight(NamedTuple):
    """What an analysis reads: the encoder, EF, the channels of one frame and the env's action space (``None``:
    actions are given as EF reads them)."""

    encode: Encoder
    ef: EgoForesight
    frame_channels: int
    action_space: spaces.Space | None


def resolve_foresight(
    model: ForesightModel | None = None, encoder: Encoder | None = None, ef: EgoForesight | None = None
) -> Foresight:
    """The :class:`Foresight` of a model following the contract, or of an explicit encoder and EF module."""
    if model is not None:
        if encoder is not None or ef is not None:
            raise ValueError("Pass either a model or encoder + ef, not both")
        if getattr(model, "ef", None) is None:
            raise ValueError(f"{type(model).__name__} has no Ego-Foresight module (model.ef is None): EF is off")
        foresight = Foresight(model.encode, model.ef, model.frame_shape[0], model.action_space)
    elif encoder is None or ef is None:
        raise ValueError("Need a model with .ef and .encode, or both encoder and ef")
    else:
        foresight = Foresight(encoder, ef, ef.frame_shape[0], None)
    if getattr(foresight.ef, "skip_channels", 0):
        raise ValueError(
            f"Analysis needs an EgoForesight without U-Net skips (skip_channels=0), got {foresight.ef.skip_channels}: "
            "model.encode returns features only, not the skip feature maps"
        )
    return foresight


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


def as_observation_batch(
    observation: np.ndarray | th.Tensor, device: th.device, frame_channels: int = FRAME_CHANNELS
) -> th.Tensor:
    """A single stacked uint8 observation (C*k, h, w) of k frames of C channels as a (1, C*k, h, w) tensor."""
    tensor = th.as_tensor(np.asarray(observation) if not isinstance(observation, th.Tensor) else observation)
    if tensor.dim() != 3 or tensor.shape[0] % frame_channels != 0 or tensor.dtype != th.uint8:
        raise ValueError(
            f"Expected one stacked uint8 observation of shape ({frame_channels} * frame_stack, height, width), "
            f"got shape {tuple(tensor.shape)} and dtype {tensor.dtype}"
        )
    return tensor.unsqueeze(0).to(device)


def action_batch(
    actions: np.ndarray | th.Tensor, ef: EgoForesight, device: th.device, action_space: spaces.Space | None = None
) -> th.Tensor:
    """T actions as EF's float (1, T, action_dim) inputs on ``device``, checked against ``ef``: the env's actions
    encoded as the hosts encode them (:func:`~sb3_ef.common.buffers.rollout_windows.encode_actions`: one-hot for
    Discrete, Box scaled to [-1, 1]) when ``action_space`` is given, else (T, action_dim) inputs as they are."""
    tensor = actions if isinstance(actions, th.Tensor) else th.as_tensor(np.asarray(actions, dtype=np.float32))
    if action_space is not None:
        size = get_action_dim(action_space)
        if tensor.dim() == 0 or tensor.numel() != len(tensor) * size:
            raise ValueError(f"Expected (steps, {size}) actions of {action_space}, got shape {tuple(tensor.shape)}")
        tensor = encode_actions(tensor.reshape(len(tensor), size), action_space)
    if tensor.dim() != 2 or tensor.shape[0] < 1:
        raise ValueError(f"Expected actions of shape (steps, action_dim), got {tuple(tensor.shape)}")
    expected_dim = getattr(ef, "action_dim", tensor.shape[1])
    if tensor.shape[1] != expected_dim:
        raise ValueError(f"Expected actions with {expected_dim} dimensions, got {tensor.shape[1]}")
    return tensor.float().unsqueeze(0).to(device)


def context_frames(observation: np.ndarray, frame_channels: int = FRAME_CHANNELS) -> np.ndarray:
    """The frames of a channels-first stacked observation, oldest first, as uint8 (k, h, w, frame_channels)."""
    observation = np.asarray(observation)
    if observation.ndim != 3 or observation.shape[0] % frame_channels != 0:
        raise ValueError(
            f"Expected a ({frame_channels} * frame_stack, height, width) observation, got shape {observation.shape}"
        )
    stacked = observation.reshape(-1, frame_channels, *observation.shape[1:])
    return np.ascontiguousarray(stacked.transpose(0, 2, 3, 1))


def frame_images(frames: np.ndarray) -> np.ndarray:
    """uint8 frames (..., h, w, C) as RGB images (..., h, w, 3): RGB as it is, other frames (grey: C = 1) as the
    grey of their channels' mean."""
    frames = np.asarray(frames)
    if frames.shape[-1] == 3:
        return frames
    grey = frames.mean(axis=-1, keepdims=True).round().astype(np.uint8)
    return np.repeat(grey, 3, axis=-1)


def to_uint8_frames(frames: th.Tensor) -> np.ndarray:
    """(..., C, h, w) floats in [0, 1] -> (..., h, w, C) uint8."""
    array = (frames.detach().clamp(0, 1) * 255).round().to(th.uint8).cpu().numpy()
    return np.moveaxis(array, -3, -1)


def figure_eight_actions(steps: int, action_dim: int, period: int = 40) -> np.ndarray:
    """A probe, float32 (steps, action_dim): a figure-eight velocity ``cos(w t), cos(2 w t)`` on two components
    (actions of a Box in [-1, 1])."""
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
    """The T uint8 (T, h, w, C) frames EF predicts open loop after ``actions`` (a model's: the env's actions; an
    ``ef``'s: its inputs, :func:`action_batch`) from one stacked observation."""
    foresight = resolve_foresight(model, encoder, ef)
    device = module_device(foresight.ef)
    with eval_mode(foresight.ef, encoder):
        features = foresight.encode(as_observation_batch(observation, device, foresight.frame_channels))
        frames = foresight.ef.predict(features, action_batch(actions, foresight.ef, device, foresight.action_space))
    return to_uint8_frames(frames[0])


def frame_grid(rows: list[np.ndarray], spacing: int = 2) -> np.ndarray:
    """Lay out rows of uint8 (n, h, w, C) frames in one RGB image (:func:`frame_images`); short rows are padded with
    black."""
    if not rows:
        raise ValueError("frame_grid needs at least one row of frames")
    height, width = rows[0].shape[1:3]
    for row in rows:
        if row.ndim != 4 or row.shape[1:3] != (height, width):
            raise ValueError(f"Expected rows of (n, {height}, {width}, channels) frames, got {row.shape}")
    columns = max(len(row) for row in rows)
    grid = np.zeros(
        (len(rows) * (height + spacing) - spacing, columns * (width + spacing) - spacing, 3), dtype=np.uint8
    )
    for row_index, row in enumerate(rows):
        for column_index, frame in enumerate(row):
            top, left = row_index * (height + spacing), column_index * (width + spacing)
            grid[top : top + height, left : left + width] = frame_images(frame)
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
    """PNG with one row each: the context frames (k, h, w, C), the predicted frames, and the true frames if given."""
    rows = [context, predicted] if true is None else [context, predicted, true]
    return save_image(path, frame_grid(rows))


def save_video(path: str | os.PathLike, predicted: np.ndarray, true: np.ndarray | None = None, fps: int = 10) -> str:
    """GIF or MP4 (by suffix; MP4 needs ``imageio-ffmpeg``) of the predicted frames, beside the true ones if given."""
    frames = frame_images(predicted if true is None else np.concatenate([predicted, true[: len(predicted)]], axis=2))
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
