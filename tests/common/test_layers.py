import pytest
import torch as th
from torch import nn

from sb3_ef.common.layers import NormedLinear, SimNorm, mlp


def test_simnorm_sums_to_one_per_group():
    out = SimNorm(group_dim=8)(th.randn(4, 32) * 5)
    groups = out.view(4, 4, 8)
    assert th.allclose(groups.sum(-1), th.ones(4, 4), atol=1e-6)
    assert (out >= 0).all()


def test_simnorm_rejects_indivisible_width():
    with pytest.raises(ValueError, match="divisible by 8"):
        SimNorm(8)(th.randn(2, 12))


def test_mlp_structure_and_shapes():
    net = mlp(10, [16, 16], 3, dropout=0.1)
    assert isinstance(net[0], NormedLinear) and isinstance(net[0][1], nn.Dropout)
    assert not any(isinstance(layer, nn.Dropout) for layer in net[1])
    assert isinstance(net[-1], nn.Linear)
    assert net(th.randn(5, 10)).shape == (5, 3)


def test_mlp_with_output_activation_is_normed():
    net = mlp(4, [8], 16, output_activation=SimNorm(8))
    out = net(th.randn(3, 4))
    assert th.allclose(out.view(3, 2, 8).sum(-1), th.ones(3, 2), atol=1e-6)
