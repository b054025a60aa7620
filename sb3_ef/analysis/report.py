"""One look at what EF learned on one rollout: predictions, saliency and its score against the agent mask."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import gymnasium as gym
import numpy as np

from sb3_ef.analysis.masks import MaskScores, mask_scores, threshold_saliency
from sb3_ef.analysis.prediction import (
    FRAME_CHANNELS,
    ForesightModel,
    context_frames,
    frame_grid,
    frame_images,
    predict_open_loop,
)
from sb3_ef.analysis.saliency import Saliency, compute_saliency, saliency_overlay


@dataclass(frozen=True)
class Rollout:
    """The first stacked observation, the env's T actions as SB3's buffers keep them (float, (T, action_dim)), the
    T newest frames after them ((T, h, w, C)) and the final agent mask."""

    first_observation: np.ndarray
    actions: np.ndarray
    true_frames: np.ndarray
    agent_mask: np.ndarray | None


def record_rollout(
    env: gym.Env,
    act: Callable[[np.ndarray, int], np.ndarray],
    steps: int,
    seed: int | None = None,
    frame_channels: int = FRAME_CHANNELS,
) -> Rollout:
    """Reset ``env`` and take up to ``steps`` actions ``act(observation, t)`` (fewer if the episode ends); its
    observations stack frames of ``frame_channels`` channels (a model's ``frame_shape[0]``)."""
    first_observation, _ = env.reset(seed=seed)
    observation, actions, frames = first_observation, [], []
    for step in range(steps):
        action = act(observation, step)
        observation, _, terminated, truncated, _ = env.step(action)
        actions.append(np.asarray(action, dtype=np.float32).reshape(-1))
        frames.append(observation[-frame_channels:].transpose(1, 2, 0))
        if terminated or truncated:
            break
    mask_fn = getattr(env.unwrapped, "agent_mask", None)
    agent_mask = None if mask_fn is None else np.asarray(mask_fn(), dtype=bool)
    return Rollout(first_observation, np.stack(actions), np.stack(frames), agent_mask)


@dataclass(frozen=True)
class ForesightReport:
    """EF's open-loop prediction of a rollout, the saliency of its last frame and the scores."""

    rollout: Rollout
    predicted: np.ndarray
    saliency: Saliency
    prediction_mse: float
    mask: MaskScores | None

    def prediction_image(self) -> np.ndarray:
        """Rows: context frames, predicted frames, true frames."""
        context = context_frames(self.rollout.first_observation, self.predicted.shape[-1])
        return frame_grid([context, self.predicted, self.rollout.true_frames])

    def saliency_panels(self) -> dict[str, np.ndarray]:
        """The last predicted frame, with its h_a saliency in red and with its h_s saliency in blue, by title."""
        frame = self.saliency.frame
        return {
            "predicted frame": frame_images(frame),
            "h_a saliency (red)": saliency_overlay(frame, self.saliency.agent, color=(255, 0, 0)),
            "h_s saliency (blue)": saliency_overlay(frame, self.saliency.scene, color=(0, 0, 255)),
        }

    def saliency_image(self) -> np.ndarray:
        """The :meth:`saliency_panels` side by side."""
        return frame_grid([np.stack(list(self.saliency_panels().values()))])

    def scalars(self) -> dict[str, float]:
        """``prediction_mse`` (pixels in [0, 1]) and ``mask_precision`` / ``mask_recall`` / ``mask_iou`` if scored."""
        values = {"prediction_mse": self.prediction_mse}
        if self.mask is not None:
            values.update({f"mask_{name}": value for name, value in self.mask.as_dict().items()})
        return values


def foresight_report(
    model: ForesightModel,
    rollout: Rollout,
    patch_size: int = 4,
    threshold_rule: str = "mean_std",
    num_std: float = 1.0,
    fraction: float = 0.1,
) -> ForesightReport:
    """``rollout`` predicted open loop, with saliency and mask scores of its last predicted frame."""
    predicted = predict_open_loop(rollout.first_observation, rollout.actions, model=model)
    if rollout.true_frames.shape[-1] != predicted.shape[-1]:
        raise ValueError(
            f"The rollout's frames have {rollout.true_frames.shape[-1]} channels, the model predicts frames of "
            f"{predicted.shape[-1]}: record it with frame_channels=model.frame_shape[0]"
        )
    saliency = compute_saliency(rollout.first_observation, rollout.actions, model=model, patch_size=patch_size)
    mse = float(np.mean((predicted / 255.0 - rollout.true_frames / 255.0) ** 2))
    scores = None
    if rollout.agent_mask is not None:
        predicted_mask = threshold_saliency(saliency.agent, rule=threshold_rule, num_std=num_std, fraction=fraction)
        scores = mask_scores(predicted_mask, rollout.agent_mask)
    return ForesightReport(rollout, predicted, saliency, mse, scores)
