"""How hard an auxiliary loss pulls on the encoder, next to the host's loss: ``train/aux_grad_ratio``.

The ratio ``||d aux / d encoder|| / ||d host / d encoder||`` is computed on one update in every
:data:`AUX_GRAD_RATIO_EVERY` (two extra backward passes through the encoder, keeping the graphs), so it can stay on;
a ratio near 1 means the auxiliary term moves the encoder as much as the host's loss does.
"""

from __future__ import annotations

from collections.abc import Iterable

import torch as th
from torch import nn

#: One update in this many computes the ratio (the logger keeps the mean of those since the last dump).
AUX_GRAD_RATIO_EVERY = 100


def aux_grad_ratio_due(n_updates: int, every: int = AUX_GRAD_RATIO_EVERY) -> bool:
    """Whether update number ``n_updates`` (counted from 1) computes the ratio: the first, then one in ``every``."""
    return n_updates % every == 1 or every == 1


def encoder_gradient_ratio(
    auxiliary_loss: th.Tensor, host_loss: th.Tensor, parameters: Iterable[nn.Parameter]
) -> th.Tensor:
    """The ratio of the encoder-gradient norms of ``auxiliary_loss`` (as weighted in the host's loss) and
    ``host_loss``, both graphs kept for the host's own backward pass; a detached scalar tensor (no device sync)."""
    params = [param for param in parameters if param.requires_grad]
    norms = []
    for loss in (auxiliary_loss, host_loss):
        grads = th.autograd.grad(loss, params, retain_graph=True, allow_unused=True)
        squares = [grad.detach().pow(2).sum() for grad in grads if grad is not None]
        norms.append(th.stack(squares).sum().sqrt() if squares else th.zeros((), device=loss.device))
    return norms[0] / norms[1].clamp_min(1e-12)
