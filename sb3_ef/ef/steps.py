"""Drawing the rollout length k of each Ego-Foresight update."""

from __future__ import annotations

import torch as th

STEP_SAMPLINGS = ("batch", "sample")


def draw_rollout_steps(
    future_mask: th.Tensor, horizon: int, step_sampling: str = "batch", generator: th.Generator | None = None
) -> th.Tensor:
    """Draw k in [1, horizon] for each sample of a batch; returns a (B,) long tensor on the mask's device.

    - ``"batch"``: one k ~ U{1..horizon} for the whole batch (the authors' code). Samples whose step k falls
      outside their episode are then dropped from the loss by the host's ``valid`` (the mask at k).
    - ``"sample"``: each sample draws its own k uniformly among its *valid* steps, so every sample with at
      least one valid step contributes; a sample with no valid step draws from all steps and stays invalid.

    :param future_mask: (B, H) bool, true where step t+i lies inside the episode; H >= horizon.
    """
    if step_sampling not in STEP_SAMPLINGS:
        raise ValueError(f"step_sampling must be one of {STEP_SAMPLINGS}, got {step_sampling!r}")
    if future_mask.dim() != 2 or future_mask.shape[1] < horizon:
        raise ValueError(f"Expected future_mask of shape (batch, >= {horizon}), got {tuple(future_mask.shape)}")
    batch = future_mask.shape[0]
    device = generator.device if generator is not None else future_mask.device
    if step_sampling == "batch":
        steps = th.randint(1, horizon + 1, (1,), device=device, generator=generator).expand(batch)
    else:
        weights = future_mask[:, :horizon].to(device=device, dtype=th.float32)
        weights[weights.sum(dim=1) == 0] = 1.0
        steps = th.multinomial(weights, 1, generator=generator).squeeze(1) + 1
    return steps.to(future_mask.device).contiguous()
