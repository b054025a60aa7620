"""MPPI planning in the latent space of a TD-MPC2 world model."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import torch as th

#: What ``plan(..., deterministic=True)`` returns: TD-MPC2's evaluation action or the final mean.
EVAL_ACTIONS = ("elite", "mean")


class LatentModel(Protocol):
    """What the planner needs from a world model (:class:`~sb3_ef.tdmpc2.world_model.WorldModel` provides it)."""

    action_dim: int

    def next(self, z: th.Tensor, action: th.Tensor) -> th.Tensor: ...

    def reward_value(self, z: th.Tensor, action: th.Tensor) -> th.Tensor: ...

    def pi(self, z: th.Tensor) -> tuple[th.Tensor, ...]: ...

    def q_value(self, z: th.Tensor, action: th.Tensor, reduce: str = "avg", target: bool = False) -> th.Tensor: ...


@dataclass
class MPPIPlanner:
    """MPPI with policy-prior samples and TD-MPC2's defaults, batched over envs (see docs/tdmpc2.md)."""

    horizon: int = 3
    iterations: int = 6
    num_samples: int = 512
    num_elites: int = 64
    num_pi_trajs: int = 24
    min_std: float = 0.05
    max_std: float = 2.0
    temperature: float = 0.5
    gamma: float = 0.99
    eval_action: str = "elite"

    def __post_init__(self) -> None:
        if self.horizon < 1 or self.iterations < 1:
            raise ValueError(f"horizon and iterations must be >= 1, got {self.horizon} and {self.iterations}")
        if not 0 <= self.num_pi_trajs < self.num_samples:
            raise ValueError(f"num_pi_trajs must be in [0, num_samples={self.num_samples}), got {self.num_pi_trajs}")
        if not 1 <= self.num_elites <= self.num_samples:
            raise ValueError(f"num_elites must be in [1, num_samples={self.num_samples}], got {self.num_elites}")
        if not 0 < self.min_std <= self.max_std:
            raise ValueError(f"Need 0 < min_std <= max_std, got min_std={self.min_std}, max_std={self.max_std}")
        if self.eval_action not in EVAL_ACTIONS:
            raise ValueError(f"eval_action must be one of {EVAL_ACTIONS}, got {self.eval_action!r}")

    def estimate_value(self, model: LatentModel, z: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Discounted model rewards along ``actions`` ``(..., H, A)`` from ``z`` ``(..., L)`` plus the final Q."""
        value = th.zeros(z.shape[:-1], device=z.device)
        discount = 1.0
        for t in range(actions.shape[-2]):
            value = value + discount * model.reward_value(z, actions[..., t, :])
            z = model.next(z, actions[..., t, :])
            discount *= self.gamma
        return value + discount * model.q_value(z, model.pi(z)[0], reduce="avg")

    @th.no_grad()
    def plan(
        self, model: LatentModel, z: th.Tensor, previous_mean: th.Tensor | None = None, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor]:
        """Actions ``(B, A)`` and final mean ``(B, H, A)`` from ``z`` ``(B, L)``, warm-started by ``previous_mean``."""
        batch, device = z.shape[0], z.device
        action_dim = model.action_dim
        mean = th.zeros(batch, self.horizon, action_dim, device=device)
        if previous_mean is not None:
            mean[:, :-1] = previous_mean[:, 1:]
        std = th.full_like(mean, self.max_std)
        num_random = self.num_samples - self.num_pi_trajs
        actions = th.empty(batch, self.num_samples, self.horizon, action_dim, device=device)
        if self.num_pi_trajs > 0:
            actions[:, : self.num_pi_trajs] = self._policy_trajectories(model, z)
        z = z.unsqueeze(1).expand(batch, self.num_samples, z.shape[-1])
        for _ in range(self.iterations):
            noise = th.randn(batch, num_random, self.horizon, action_dim, device=device)
            actions[:, self.num_pi_trajs :] = (mean.unsqueeze(1) + std.unsqueeze(1) * noise).clamp(-1, 1)
            value = self.estimate_value(model, z, actions).nan_to_num(0.0)
            elite_value, elite_index = th.topk(value, self.num_elites, dim=1)
            elite_actions = actions[th.arange(batch, device=device)[:, None], elite_index]  # (B, E, H, A)
            score = th.exp(self.temperature * (elite_value - elite_value.max(1, keepdim=True).values))
            score = score / score.sum(1, keepdim=True)
            weights = score[:, :, None, None]
            mean = (weights * elite_actions).sum(1)
            std = (weights * (elite_actions - mean.unsqueeze(1)).pow(2)).sum(1).sqrt().clamp(self.min_std, self.max_std)
        if deterministic and self.eval_action == "mean":
            return mean[:, 0].clamp(-1, 1), mean
        chosen = th.multinomial(score, 1).squeeze(1)
        first = elite_actions[th.arange(batch, device=device), chosen, 0]
        if deterministic:
            return first, mean
        return (first + std[:, 0] * th.randn_like(first)).clamp(-1, 1), mean

    def _policy_trajectories(self, model: LatentModel, z: th.Tensor) -> th.Tensor:
        """The policy prior rolled through the model: ``(B, num_pi_trajs, H, A)``."""
        z = z.unsqueeze(1).expand(z.shape[0], self.num_pi_trajs, z.shape[-1])
        steps = []
        for t in range(self.horizon):
            action = model.pi(z)[0]
            steps.append(action)
            if t < self.horizon - 1:
                z = model.next(z, action)
        return th.stack(steps, dim=2)
