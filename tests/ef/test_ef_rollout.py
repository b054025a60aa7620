import pytest
import torch as th

from sb3_ef.ef import RolloutBlock


def test_rollout_is_recurrent_one_action_per_step():
    block = RolloutBlock(4, 2, (16, 16))
    h_agent, actions = th.randn(3, 4), th.randn(3, 5, 2)
    states = block(h_agent, actions)
    assert states.shape == (3, 5, 4)
    manual = h_agent
    for t in range(5):
        manual = block.step(manual, actions[:, t])
        th.testing.assert_close(states[:, t], manual)


def test_rollout_has_no_residual_and_uses_normed_blocks():
    block = RolloutBlock(4, 2, (16, 16))
    layers = list(block.net)
    assert [type(m).__name__ for m in layers] == ["NormedLinear", "NormedLinear", "Linear"]
    assert isinstance(layers[0][-1], th.nn.Mish) and isinstance(layers[0][1], th.nn.LayerNorm)
    # Without a residual, zeroing the output layer predicts zero agent features whatever the input.
    th.nn.init.zeros_(layers[-1].weight)
    th.nn.init.zeros_(layers[-1].bias)
    assert block(th.randn(2, 4), th.randn(2, 3, 2)).abs().max() == 0


def test_rollout_rejects_wrong_shapes():
    block = RolloutBlock(4, 2)
    with pytest.raises(ValueError, match=r"\(batch, 4\)"):
        block(th.randn(3, 5), th.randn(3, 2, 2))
    with pytest.raises(ValueError, match=r"\(3, steps, 2\)"):
        block(th.randn(3, 4), th.randn(3, 2, 3))
