"""Momentum copies of an online module, the slow targets of the contrastive auxiliary losses (CURL's key encoder,
latent Ego-Foresight's target encoder and projection): ``copy <- (1 - tau) copy + tau online`` after updates."""

from __future__ import annotations

import copy

import torch as th
from stable_baselines3.common.utils import polyak_update
from torch import nn


def momentum_copy(module: nn.Module) -> nn.Module:
    """A copy of ``module`` whose parameters are buffers: in its state dict (saved and loaded with the module that
    holds it), moved by ``.to``, never in ``parameters()`` and so never given to an optimiser, never requiring grad."""
    copied = copy.deepcopy(module)
    for submodule in copied.modules():
        for name, parameter in list(submodule._parameters.items()):
            if parameter is not None:
                del submodule._parameters[name]
                submodule.register_buffer(name, parameter.detach())
    return copied.eval()


def momentum_update(online: nn.Module, copied: nn.Module, tau: float, what: str = "module") -> None:
    """``copied <- (1 - tau) copied + tau online`` for every parameter of ``online`` (SB3's ``polyak_update``),
    matched by name in ``copied`` (as parameters, or as buffers in a :func:`momentum_copy`); then ``online``'s own
    buffers (batch-norm statistics, if any) are copied, as SB3 does for its targets.

    :param what: the module's name in the error raised when ``copied`` was not copied from a module like ``online``.
    """
    with th.no_grad():
        _move(online, copied, tau, what)


def _move(online: nn.Module, copied: nn.Module, tau: float, what: str) -> None:
    parameters = dict(online.named_parameters())
    tensors = {**dict(copied.named_parameters()), **dict(copied.named_buffers())}
    if any(name not in tensors or tensors[name].shape != value.shape for name, value in parameters.items()):
        raise ValueError(
            f"The momentum copy of the {what} was not copied from a module like the one given (parameters "
            f"{list(parameters)[:3]}...): pass the {what} the copy was built from"
        )
    polyak_update(parameters.values(), [tensors[name] for name in parameters], tau)
    for name, buffer in online.named_buffers():
        tensors[name].copy_(buffer)
