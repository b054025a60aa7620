"""Which pixels of a predicted frame each half of the representation (h_a, h_s) controls (paper Section 4.2)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th

from sb3_ef.analysis.prediction import (
    Encoder,
    ForesightModel,
    action_batch,
    as_observation_batch,
    eval_mode,
    frame_images,
    module_device,
    resolve_foresight,
    to_uint8_frames,
)
from sb3_ef.ef import EgoForesight


@dataclass(frozen=True)
class Saliency:
    """Saliency of one decoded frame: ``agent`` / ``scene`` maps in [0, 1] and the raw gradient norms per patch."""

    frame: np.ndarray
    agent: np.ndarray
    scene: np.ndarray
    agent_patches: np.ndarray
    scene_patches: np.ndarray


def _normalise(patches: np.ndarray, patch_size: int) -> np.ndarray:
    peak = patches.max()
    scaled = patches / peak if peak > 0 else np.zeros_like(patches)
    return np.kron(scaled, np.ones((patch_size, patch_size)))


def decoder_saliency(
    ef: EgoForesight,
    h_scene: th.Tensor,
    h_agent: th.Tensor,
    patch_size: int = 4,
    skip: th.Tensor | None = None,
    chunk_size: int = 128,
) -> Saliency:
    """Saliency of ``ef.decode(h_scene, h_agent)`` for one frame, ``chunk_size`` patches per backward call."""
    if h_scene.dim() != 2 or h_agent.dim() != 2 or h_scene.shape[0] != 1 or h_agent.shape[0] != 1:
        raise ValueError(
            f"Expected h_scene (1, scene_dim) and h_agent (1, agent_dim), got {tuple(h_scene.shape)} "
            f"and {tuple(h_agent.shape)}"
        )
    h_scene = h_scene.detach().clone().requires_grad_(True)
    h_agent = h_agent.detach().clone().requires_grad_(True)
    with th.enable_grad(), eval_mode(ef):
        frame = ef.decode(h_scene, h_agent, skip)
        _, channels, height, width = frame.shape
        if height % patch_size or width % patch_size:
            raise ValueError(f"Frame size {height}x{width} is not divisible by patch_size={patch_size}")
        rows, columns = height // patch_size, width // patch_size
        patch_sums = frame[0].reshape(channels, rows, patch_size, columns, patch_size).sum(dim=(0, 2, 4)).flatten()
        basis = th.eye(patch_sums.numel(), device=patch_sums.device, dtype=patch_sums.dtype)
        agent_norms, scene_norms = [], []
        for start in range(0, patch_sums.numel(), chunk_size):
            chunk = basis[start : start + chunk_size]
            grad_agent, grad_scene = th.autograd.grad(
                patch_sums, (h_agent, h_scene), grad_outputs=chunk, retain_graph=True, is_grads_batched=True
            )
            agent_norms.append(grad_agent.flatten(1).norm(dim=1))
            scene_norms.append(grad_scene.flatten(1).norm(dim=1))
    agent_patches = th.cat(agent_norms).reshape(rows, columns).cpu().numpy()
    scene_patches = th.cat(scene_norms).reshape(rows, columns).cpu().numpy()
    agent, scene = _normalise(agent_patches, patch_size), _normalise(scene_patches, patch_size)
    return Saliency(to_uint8_frames(frame[0]), agent, scene, agent_patches, scene_patches)


def compute_saliency(
    observation: np.ndarray | th.Tensor,
    actions: np.ndarray | th.Tensor | None = None,
    model: ForesightModel | None = None,
    encoder: Encoder | None = None,
    ef: EgoForesight | None = None,
    patch_size: int = 4,
) -> Saliency:
    """Saliency of EF's prediction after ``actions`` (``None``: its reconstruction of the newest frame)."""
    encode, foresight, channels, action_space = resolve_foresight(model, encoder, ef)
    device = module_device(foresight)
    with th.no_grad(), eval_mode(foresight, encoder):
        h_scene, h_agent = foresight.split(encode(as_observation_batch(observation, device, channels)))
        if actions is not None:
            h_agent = foresight.rollout(h_agent, action_batch(actions, foresight, device, action_space))[:, -1]
    return decoder_saliency(foresight, h_scene, h_agent, patch_size=patch_size)


def saliency_overlay(
    frame: np.ndarray, saliency_map: np.ndarray, alpha: float = 0.7, color: tuple[int, int, int] = (255, 0, 0)
) -> np.ndarray:
    """Blend ``color`` into a uint8 (h, w, C) frame (:func:`~sb3_ef.analysis.prediction.frame_images`) in
    proportion to a [0, 1] (h, w) map: weight ``alpha * map``; an RGB image."""
    if frame.shape[:2] != saliency_map.shape:
        raise ValueError(f"Frame {frame.shape[:2]} and saliency map {saliency_map.shape} differ in size")
    weight = alpha * np.clip(saliency_map, 0.0, 1.0)[..., None]
    blended = (1.0 - weight) * frame_images(frame).astype(np.float64) + weight * np.asarray(color, dtype=np.float64)
    return blended.round().astype(np.uint8)
