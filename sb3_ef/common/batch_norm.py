"""Forward passes that leave batch-norm running statistics untouched."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

from torch import nn


@contextmanager
def running_stats_kept(module: nn.Module) -> Iterator[None]:
    """Within the block, the batch-norm layers of ``module`` normalise as they would but do not update their
    running statistics (in training mode they normalise by the batch's statistics either way; in evaluation mode
    they update nothing anyway).

    For a forward that is not the host algorithm's own (an auxiliary loss on a shared encoder): SB3's SAC, TD3 and
    TQC copy the critic's running statistics to the critic target with their target updates, so the statistics must
    stay those of the host's own forwards for the target to keep equal ones.
    """
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
