"""TD-MPC2's gradient clipping, with an auxiliary loss's gradient clipped on its own (docs/tdmpc2.md)."""

from __future__ import annotations

import torch as th


def clipped_world_model_gradients(
    optimizer: th.optim.Optimizer, host_loss: th.Tensor, auxiliary_loss: th.Tensor | None, max_norm: float
) -> dict[str, th.Tensor]:
    """Backpropagate and clip the auxiliary gradient apart (see docs/tdmpc2.md); returns the pre-clip norms."""
    host_params, auxiliary_params = _parameter_groups(optimizer)
    auxiliary_grads = None
    if auxiliary_loss is not None:
        auxiliary_grads = th.autograd.grad(auxiliary_loss, auxiliary_params, retain_graph=True, allow_unused=True)
    host_loss.backward()
    norms = {"grad_norm": th.nn.utils.clip_grad_norm_(host_params, max_norm)}
    if auxiliary_grads is not None:
        pairs = [
            (param, grad) for param, grad in zip(auxiliary_params, auxiliary_grads, strict=True) if grad is not None
        ]
        auxiliary_norm = th.nn.utils.get_total_norm([grad for _, grad in pairs])
        scale = (max_norm / (auxiliary_norm + 1e-6)).clamp(max=1.0)
        for param, grad in pairs:
            if param.grad is None:
                # The parameter's memory layout (channels-last weights), which fused Adam assumes.
                param.grad = th.empty_like(param).copy_(grad).mul_(scale)
            else:
                param.grad.add_(grad * scale)
        norms["auxiliary_grad_norm"] = auxiliary_norm
    return norms


def _parameter_groups(optimizer: th.optim.Optimizer) -> tuple[list[th.nn.Parameter], list[th.nn.Parameter]]:
    """The parameters of the host's clip (all but ``auxiliary``) and of the auxiliary's (``encoder``, ``auxiliary``)."""
    groups = {group["name"]: group["params"] for group in optimizer.param_groups}
    host_params = [param for name, params in groups.items() if name != "auxiliary" for param in params]
    return host_params, [*groups["encoder"], *groups.get("auxiliary", [])]
