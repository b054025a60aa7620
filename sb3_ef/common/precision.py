"""The ``precision`` option of every algorithm and of offline pretraining: float32 or bfloat16 mixed precision.

``"bf16"`` runs the matrix maths of an update (convolutions, linear layers) in bfloat16 under ``torch.autocast``,
forward and backward; weights, gradients, optimiser states, replay frames and targets stay float32 (or uint8), and
so does elementwise maths on them (the EF target's ``/ 255``, Polyak updates, optimiser steps), which autocast
leaves alone. A network output that feeds a softmax, a log-probability or a loss's reduction is made float32 where
it leaves the network (``.float()``, a no-op in float32). A host adds the option in two lines: its update (and
planner) under :func:`autocast`, and, when the update is SB3's own ``train()`` (SAC, PPO, ...), its policy's
distribution heads given float32 outputs by :func:`float32_outputs` (docs/precision.md).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import torch as th
from stable_baselines3.common.utils import get_device
from torch import nn

from sb3_ef.common.validation import PRECISIONS, check_choice


def check_precision(precision: Any, device: th.device | str) -> str:
    """``precision`` if it is one of :data:`PRECISIONS` and ``device`` can run it; else a ``ValueError`` naming both."""
    check_choice("precision", precision, PRECISIONS)
    if precision == "bf16":
        resolved = get_device(device)  # "auto" and a missing GPU as the algorithms resolve them
        if resolved.type not in ("cpu", "cuda"):
            raise ValueError(f"precision='bf16' runs on 'cpu' and 'cuda' devices, got device {str(resolved)!r}")
        if resolved.type == "cuda" and th.cuda.get_device_capability(resolved) < (8, 0):  # emulated: slower
            raise ValueError(
                f"precision='bf16' needs a GPU with native bfloat16 maths (compute capability 8.0 or newer), and "
                f"{th.cuda.get_device_name(resolved)} has none: use precision='fp32'"
            )
    return precision


@contextmanager
def autocast(precision: str, device: th.device) -> Iterator[None]:
    """Run the block in ``precision`` on ``device``'s type: nothing changes for ``"fp32"``.

    The cast weights are not cached: an update steps its optimisers inside the block, and a cached cast would give
    the next forward pass the weights from before the step.
    """
    if precision == "fp32":
        yield
        return
    with th.autocast(device.type, dtype=th.bfloat16, cache_enabled=False):
        yield


def float32(device_type: str) -> th.autocast:
    """A block computed in float32 inside :func:`autocast` (its inputs ``.float()``-ed by the caller)."""
    return th.autocast(device_type, enabled=False)


def float32_outputs(*modules: nn.Module | None) -> None:
    """Make each of ``modules`` (``None`` and non-modules skipped) return float32: the log-probability maths that
    follows, in code that is not ours (SB3's distributions), is then float32 under :func:`autocast`."""
    for module in modules:
        if isinstance(module, nn.Module):
            module.register_forward_hook(_float32_output)


def _float32_output(module: nn.Module, inputs: Any, output: th.Tensor) -> th.Tensor:
    return output.float()
