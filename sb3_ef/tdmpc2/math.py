"""TD-MPC2 numerics: symlog/symexp, two-hot discrete regression and the reference's heuristics."""

from __future__ import annotations

import torch as th
from torch.nn import functional as F


def symlog(x: th.Tensor) -> th.Tensor:
    """``sign(x) * log(1 + |x|)``."""
    return th.sign(x) * th.log1p(x.abs())


def symexp(x: th.Tensor) -> th.Tensor:
    """Inverse of :func:`symlog`."""
    return th.sign(x) * th.expm1(x.abs())


class TwoHot:
    """Discrete regression of scalars on ``num_bins`` evenly spaced symlog bins (TD-MPC2, DreamerV3)."""

    def __init__(self, num_bins: int = 101, vmin: float = -10.0, vmax: float = 10.0):
        if num_bins < 2:
            raise ValueError(f"TwoHot needs at least 2 bins, got num_bins={num_bins}")
        if not vmin < vmax:
            raise ValueError(f"TwoHot needs vmin < vmax, got vmin={vmin}, vmax={vmax}")
        self.num_bins = num_bins
        self.vmin = vmin
        self.vmax = vmax
        self.bin_size = (vmax - vmin) / (num_bins - 1)

    def encode(self, x: th.Tensor) -> th.Tensor:
        """Scalars of any shape -> two-hot vectors with a trailing ``num_bins`` axis (clamped to the range)."""
        position = (symlog(x).clamp(self.vmin, self.vmax) - self.vmin) / self.bin_size
        # The lower bin stops one short of the end so that vmax lands on the last bin with weight 1.
        lower = position.floor().clamp(max=self.num_bins - 2)
        upper_weight = (position - lower).unsqueeze(-1)
        lower = lower.long().unsqueeze(-1)
        target = th.zeros(*x.shape, self.num_bins, dtype=x.dtype, device=x.device)
        target.scatter_(-1, lower, 1.0 - upper_weight)
        target.scatter_(-1, lower + 1, upper_weight)
        return target

    def decode(self, logits: th.Tensor) -> th.Tensor:
        """Logits ``(..., num_bins)`` -> expected scalar ``(...)`` (softmax mean in symlog space, then symexp)."""
        logits = logits.float()  # bf16 logits (mixed precision): softmax and symexp in float32
        bins = th.linspace(self.vmin, self.vmax, self.num_bins, dtype=logits.dtype, device=logits.device)
        return symexp((F.softmax(logits, dim=-1) * bins).sum(-1))

    def cross_entropy(self, logits: th.Tensor, target: th.Tensor) -> th.Tensor:
        """Cross-entropy between logits ``(..., num_bins)`` and the two-hot encoding of scalars ``(...)``."""
        return -(self.encode(target) * F.log_softmax(logits.float(), dim=-1)).sum(-1)  # float32, as decode


def discount_from_episode_length(
    episode_length: int, denominator: float = 5.0, minimum: float = 0.95, maximum: float = 0.995
) -> float:
    """TD-MPC2's discount heuristic: ``(L/5 - 1) / (L/5)`` clipped to [0.95, 0.995] (0.99 for 500-step episodes)."""
    if episode_length <= 0:
        raise ValueError(f"episode_length must be positive, got {episode_length}")
    fraction = episode_length / denominator
    return min(max((fraction - 1) / fraction, minimum), maximum)


def seed_steps_from_episode_length(episode_length: int, minimum: int = 1000, episodes: int = 5) -> int:
    """TD-MPC2's seed steps: ``max(1000, 5 x episode length)`` agent steps (2500 for 500-step episodes)."""
    if episode_length <= 0:
        raise ValueError(f"episode_length must be positive, got {episode_length}")
    return max(minimum, episodes * episode_length)


def planning_iterations(action_dim: int, iterations: int = 6, large_action_dim: int = 20, extra: int = 2) -> int:
    """TD-MPC2's MPPI iterations: ``iterations``, 2 more when ``action_dim >= 20`` (humanoid, dog)."""
    if isinstance(iterations, bool) or not isinstance(iterations, int) or iterations < 1:
        raise ValueError(f"iterations must be a positive integer, got {iterations!r}")
    return iterations + extra * int(action_dim >= large_action_dim)


def update_q_scale(q_scale: th.Tensor, q_values: th.Tensor, tau: float) -> None:
    """Move ``q_scale`` by ``tau`` towards the 5-95 percentile range of ``q_values``, at least 1 (``RunningScale``)."""
    low, high = th.quantile(q_values, th.tensor([0.05, 0.95], device=q_values.device))
    q_scale.lerp_(th.clamp(high - low, min=1.0), tau)
