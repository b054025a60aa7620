"""Small reusable layers in TD-MPC2's style (normed linear blocks, MLPs, SimNorm) and DrQ-v2's initialisation."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import torch as th
from torch import nn
from torch.nn import functional as F


class NormedLinear(nn.Sequential):
    """Linear -> (Dropout) -> LayerNorm -> activation (Mish by default)."""

    def __init__(self, in_dim: int, out_dim: int, dropout: float = 0.0, activation: nn.Module | None = None):
        layers: list[nn.Module] = [nn.Linear(in_dim, out_dim)]
        if dropout > 0:
            layers.append(nn.Dropout(dropout))
        layers += [nn.LayerNorm(out_dim), activation if activation is not None else nn.Mish()]
        super().__init__(*layers)


class SimNorm(nn.Module):
    """Simplicial normalisation: a softmax over consecutive groups of ``group_dim`` features."""

    def __init__(self, group_dim: int = 8):
        super().__init__()
        self.group_dim = group_dim

    def forward(self, x: th.Tensor) -> th.Tensor:
        if x.shape[-1] % self.group_dim != 0:
            raise ValueError(f"SimNorm needs a feature size divisible by {self.group_dim}, got {x.shape[-1]}")
        groups = x.float().unflatten(-1, (-1, self.group_dim))  # a float32 softmax of bf16 outputs (mixed precision)
        return F.softmax(groups, dim=-1).flatten(-2)

    def extra_repr(self) -> str:
        return f"group_dim={self.group_dim}"


def mlp(
    in_dim: int,
    hidden_dims: list[int] | tuple[int, ...],
    out_dim: int,
    output_activation: nn.Module | None = None,
    dropout: float = 0.0,
) -> nn.Sequential:
    """An MLP of :class:`NormedLinear` blocks; ``dropout`` on the first hidden layer only, as in TD-MPC2's Q heads."""
    dims = [in_dim, *hidden_dims]
    layers: list[nn.Module] = [
        NormedLinear(dims[i], dims[i + 1], dropout=dropout if i == 0 else 0.0) for i in range(len(dims) - 1)
    ]
    if output_activation is None:
        layers.append(nn.Linear(dims[-1], out_dim))
    else:
        layers.append(NormedLinear(dims[-1], out_dim, activation=output_activation))
    return nn.Sequential(*layers)


def orthogonal_init(module: nn.Module) -> None:
    """DrQ-v2's (and SEAR's) initialisation for ``module.apply``: orthogonal weights, ReLU gain for convolutions."""
    if isinstance(module, nn.Linear):
        nn.init.orthogonal_(module.weight)
        nn.init.zeros_(module.bias)
    elif isinstance(module, (nn.Conv2d, nn.ConvTranspose2d)):
        nn.init.orthogonal_(module.weight, nn.init.calculate_gain("relu"))
        if module.bias is not None:
            nn.init.zeros_(module.bias)


@contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Inside the block ``module``'s parameters take no gradient (an actor's loss through its critic); not compiled."""
    module.requires_grad_(False)
    try:
        yield
    finally:
        module.requires_grad_(True)
