"""Momentum copies of an online module, the slow targets of CURL and latent Ego-Foresight."""

from __future__ import annotations

import copy

import torch as th
from stable_baselines3.common.utils import polyak_update
from torch import nn


def momentum_copy(module: nn.Module) -> nn.Module:
    """A copy of ``module`` whose parameters are buffers: saved in its state dict, never given to an optimiser."""
    copied = copy.deepcopy(module)
    for submodule in copied.modules():
        for name, parameter in list(submodule._parameters.items()):
            if parameter is not None:
                del submodule._parameters[name]
                submodule.register_buffer(name, parameter.detach())
    return copied.eval()


def momentum_update(online: nn.Module, copied: nn.Module, tau: float, what: str = "module") -> None:
    """``copied <- (1 - tau) copied + tau online`` for each parameter by name; buffers copied, as SB3 does.

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
