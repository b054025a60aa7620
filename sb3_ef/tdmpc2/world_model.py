"""TD-MPC2's implicit world model for pixels: encoder, latent dynamics, reward, policy prior and Q-ensemble."""

from __future__ import annotations

import copy
import math
from typing import NamedTuple

import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ef.common.layers import SimNorm, mlp
from sb3_ef.tdmpc2.math import TwoHot

#: The only frame size the conv stack maps to a 4x4 grid (as in TD-MPC2).
FRAME_SIZE = 64


class PolicyOutput(NamedTuple):
    """A squashed Gaussian sample of the policy prior."""

    action: th.Tensor  # sampled action in [-1, 1]
    mean: th.Tensor  # tanh of the Gaussian mean
    log_prob: th.Tensor  # log-probability of ``action`` (tanh-corrected), shape (...,)
    scaled_entropy: th.Tensor  # TD-MPC2's entropy term: -action_dim x the Gaussian (pre-tanh) log-prob, (...,)


def encode_frames(encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    """TD-MPC2's encoder on stacked frames in [0, 255], scaled to ``obs / 255 - 0.5``."""
    return encoder(observations.float() / 255.0 - 0.5)


class WorldModel(nn.Module):
    """TD-MPC2's heads ``encode``, ``next``, ``reward``, ``pi`` and ``q`` on a SimNorm latent (see docs/tdmpc2.md).

    :param in_channels: channels of the stacked observation (3 * frame stack).
    :param action_dim: size of the continuous action.
    :param num_channels: conv channels; the latent size is ``num_channels * 16``.
    :param mlp_dim: hidden size of every MLP head.
    :param num_q: size of the Q-ensemble.
    :param dropout: dropout of the first layer of each Q head.
    :param simnorm_dim: SimNorm group size.
    :param two_hot: the discrete-regression bins shared by the reward and Q heads.
    :param log_std_min: lower bound of the policy prior's log std.
    :param log_std_max: upper bound of the policy prior's log std.
    """

    def __init__(
        self,
        in_channels: int,
        action_dim: int,
        num_channels: int = 32,
        mlp_dim: int = 512,
        num_q: int = 5,
        dropout: float = 0.01,
        simnorm_dim: int = 8,
        two_hot: TwoHot | None = None,
        log_std_min: float = -10.0,
        log_std_max: float = 2.0,
    ):
        super().__init__()
        if num_q < 2:
            raise ValueError(f"The Q-ensemble needs at least 2 heads (min of 2 random heads), got num_q={num_q}")
        self.two_hot = two_hot if two_hot is not None else TwoHot()
        self.latent_dim = num_channels * 4 * 4
        self.action_dim = action_dim
        self.num_q = num_q
        self.log_std_min = log_std_min
        self.log_std_max = log_std_max
        num_bins = self.two_hot.num_bins
        hidden = (mlp_dim, mlp_dim)
        self.encoder = nn.Sequential(
            nn.Conv2d(in_channels, num_channels, 7, stride=2),
            nn.ReLU(),
            nn.Conv2d(num_channels, num_channels, 5, stride=2),
            nn.ReLU(),
            nn.Conv2d(num_channels, num_channels, 3, stride=2),
            nn.ReLU(),
            nn.Conv2d(num_channels, num_channels, 3, stride=1),
            nn.Flatten(),
            SimNorm(simnorm_dim),
        )
        self.dynamics = mlp(
            self.latent_dim + action_dim, hidden, self.latent_dim, output_activation=SimNorm(simnorm_dim)
        )
        self.reward_head = mlp(self.latent_dim + action_dim, hidden, num_bins)
        self.pi_head = mlp(self.latent_dim, hidden, 2 * action_dim)
        self.q_heads = nn.ModuleList(
            [mlp(self.latent_dim + action_dim, hidden, num_bins, dropout=dropout) for _ in range(num_q)]
        )
        self.apply(_init_linear)
        # Zero-initialised output layers: reward and Q start at exactly 0 (TD-MPC2).
        for head in [self.reward_head, *self.q_heads]:
            nn.init.zeros_(head[-1].weight)
        self.target_q_heads = copy.deepcopy(self.q_heads).requires_grad_(False).eval()

    def train(self, mode: bool = True) -> WorldModel:
        """Switch train/eval mode; the target Q-ensemble stays in eval mode (no dropout)."""
        super().train(mode)
        self.target_q_heads.eval()
        return self

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Stacked frames ``(B, C, 64, 64)`` (uint8 or float in [0, 255]) -> SimNorm latent ``(B, latent_dim)``."""
        return encode_frames(self.encoder, observations)

    def next(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        return self.dynamics(th.cat([z, action], dim=-1))

    def reward(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        return self.reward_head(th.cat([z, action], dim=-1))

    def reward_value(self, z: th.Tensor, action: th.Tensor) -> th.Tensor:
        return self.two_hot.decode(self.reward(z, action))

    def pi(self, z: th.Tensor) -> PolicyOutput:
        """A reparameterised sample of the tanh-squashed Gaussian policy prior."""
        mean, log_std = self.pi_head(z).float().chunk(2, dim=-1)  # the log-prob maths in float32 (mixed precision)
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (th.tanh(log_std) + 1)
        noise = th.randn_like(mean)
        action = mean + noise * log_std.exp()
        gaussian_log_prob = (-0.5 * noise.pow(2) - log_std - 0.5 * math.log(2 * math.pi)).sum(-1)
        action = th.tanh(action)
        log_prob = gaussian_log_prob - th.log(F.relu(1 - action.pow(2)) + 1e-6).sum(-1)
        return PolicyOutput(action, th.tanh(mean), log_prob, -self.action_dim * gaussian_log_prob)

    def q(self, z: th.Tensor, action: th.Tensor, target: bool = False) -> th.Tensor:
        """Logits of every Q head, ``(num_q, ..., num_bins)``; ``target`` uses the Polyak-averaged copy."""
        heads = self.target_q_heads if target else self.q_heads
        za = th.cat([z, action], dim=-1)
        return th.stack([head(za) for head in heads])

    def q_value(self, z: th.Tensor, action: th.Tensor, reduce: str = "avg", target: bool = False) -> th.Tensor:
        """Scalar Q from two random heads, their ``"min"`` (TD targets) or ``"avg"`` (planning, policy)."""
        if reduce not in ("min", "avg"):
            raise ValueError(f"reduce must be 'min' or 'avg', got {reduce!r}")
        # All heads, then two picked by a tensor index (as the reference): one compiled graph, eager's random draws.
        values = self.two_hot.decode(self.q(z, action, target)[th.randperm(self.num_q, device=z.device)[:2]])
        return values.min(0).values if reduce == "min" else values.mean(0)

    @th.no_grad()
    def soft_update_target_q(self, tau: float) -> None:
        for target, online in zip(self.target_q_heads.parameters(), self.q_heads.parameters(), strict=True):
            target.lerp_(online, tau)


def _init_linear(module: nn.Module) -> None:
    """Truncated-normal (std 0.02) weights and zero biases for linear layers, as TD-MPC2."""
    if isinstance(module, nn.Linear):
        nn.init.trunc_normal_(module.weight, std=0.02)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
