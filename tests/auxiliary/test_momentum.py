"""The momentum update CURL's key encoder and latent EF's target share: SB3's polyak step matched by name, on a
copy whose weights are parameters (CURL's critic target) or buffers (:func:`momentum_copy`); online buffers copied."""

from __future__ import annotations

import copy

import pytest
import torch as th
from torch import nn

from sb3_ef.auxiliary.momentum import momentum_copy, momentum_update


@pytest.mark.parametrize("make_copy", [copy.deepcopy, momentum_copy], ids=["parameters", "buffers"])
def test_the_copy_moves_by_tau_towards_the_online_module(make_copy):
    online = nn.Sequential(nn.Linear(4, 3), nn.BatchNorm1d(3))
    copied = make_copy(online)
    before = {name: value.clone() for name, value in copied.state_dict().items()}
    with th.no_grad():
        for parameter in online.parameters():
            parameter.add_(1.0)
    online(th.randn(8, 4))  # moves the batch-norm statistics
    momentum_update(online, copied, 0.1)
    state = copied.state_dict()
    for name, parameter in online.named_parameters():
        th.testing.assert_close(state[name], 0.9 * before[name] + 0.1 * parameter.detach())
        assert state[name].grad is None
    assert th.equal(state["1.running_mean"], online[1].running_mean)
    with pytest.raises(ValueError, match="momentum copy of the key encoder was not copied from a module like"):
        momentum_update(nn.Linear(4, 5), copied, 0.1, "key encoder")
