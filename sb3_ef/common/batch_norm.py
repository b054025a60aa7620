"""Forward passes that leave batch-norm running statistics untouched."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from torch import nn


@contextmanager
def running_stats_kept(module: nn.Module) -> Iterator[None]:
    """Within the block, ``module``'s batch-norm layers keep their running statistics (for auxiliary forwards)."""
    layers = [
        layer
        for layer in module.modules()
        if isinstance(layer, nn.modules.batchnorm._BatchNorm) and layer.training and layer.track_running_stats
    ]
    for layer in layers:
        layer.track_running_stats = False
    try:
        yield
    finally:
        for layer in layers:
            layer.track_running_stats = True
