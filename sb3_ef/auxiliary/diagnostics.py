"""How hard an auxiliary loss pulls on the encoder, next to the host's loss: ``train/aux_grad_ratio``.

The ratio ``||d aux / d encoder|| / ||d host / d encoder||`` is computed on one update in every
:data:`AUX_GRAD_RATIO_EVERY`, so it can stay on; a ratio near 1 means the auxiliary term moves the encoder as much
as the host's loss does. A host that adds the auxiliary loss to its own differentiates both apart
(:func:`encoder_gradient_ratio`: two extra backward passes through the encoder, keeping the graphs); a host whose
auxiliary step is separate reads the gradients its two backward passes leave (:func:`gradient_norm`, no extra pass).
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
    norms = [
        _norm(th.autograd.grad(loss, params, retain_graph=True, allow_unused=True), loss.device)
        for loss in (auxiliary_loss, host_loss)
    ]
    return norms[0] / norms[1].clamp_min(1e-12)


def gradient_norm(parameters: Iterable[nn.Parameter]) -> th.Tensor:
    """The 2-norm of the ``.grad`` the last backward pass left on ``parameters`` (those without one count as 0), as
    a detached scalar tensor (no device sync)."""
    params = list(parameters)
    return _norm([param.grad for param in params], params[0].device if params else th.device("cpu"))


def gradient_norm_ratio(parameters: Iterable[nn.Parameter], host_norm: th.Tensor) -> th.Tensor:
    """:func:`gradient_norm` of ``parameters`` over ``host_norm``: the ratio of a separate auxiliary step, whose
    host's encoder-gradient norm was read at the host's own step."""
    return gradient_norm(parameters) / host_norm.clamp_min(1e-12)


def _norm(grads: Iterable[th.Tensor | None], device: th.device) -> th.Tensor:
    squares = [grad.detach().pow(2).sum() for grad in grads if grad is not None]
    return th.stack(squares).sum().sqrt() if squares else th.zeros((), device=device)
