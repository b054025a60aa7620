"""SEAR's agent masks, to score beside EF's h_a saliency on the same frames."""

from __future__ import annotations

import numpy as np
import torch as th

from sb3_ef.analysis.prediction import as_observation_batch, eval_mode, module_device
from sb3_ef.sear import SEAR, SEARLoss


def decoded_agent_masks(model: SEAR, observation: np.ndarray) -> np.ndarray:
    """SEAR's agent-pixel probabilities, ``(frame_stack, h, w)`` in [0, 1], of one stacked uint8 observation."""
    auxiliary = getattr(model, "auxiliary", None)
    if not isinstance(auxiliary, SEARLoss):
        raise TypeError(f"Expected a SEAR model (its auxiliary loss a SEARLoss), got {type(model).__name__}")
    batch = as_observation_batch(observation, module_device(model.policy))
    if tuple(batch.shape[1:]) != auxiliary.observation_shape:
        raise ValueError(
            f"The model was trained on observations of shape {auxiliary.observation_shape}, "
            f"got {tuple(batch.shape[1:])}"
        )
    with th.no_grad(), eval_mode(model.policy, auxiliary):
        _, masks = auxiliary.decode(model.policy.encode(batch))
    return masks[0].float().cpu().numpy()
