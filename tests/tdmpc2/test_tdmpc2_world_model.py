import pytest
import torch as th

from sb3_ef.tdmpc2.world_model import WorldModel


def make_model(**kwargs):
    return WorldModel(in_channels=9, action_dim=2, num_channels=8, mlp_dim=32, num_q=3, **kwargs)


def test_heads_have_the_expected_shapes_and_ranges():
    model = make_model()
    obs = th.randint(0, 256, (4, 9, 64, 64), dtype=th.uint8)
    z = model.encode(obs)
    assert z.shape == (4, 128) == (4, model.latent_dim)
    # SimNorm: every group of 8 features is a probability vector.
    th.testing.assert_close(z.view(4, -1, 8).sum(-1), th.ones(4, 16))
    action = th.rand(4, 2) * 2 - 1
    next_z = model.next(z, action)
    th.testing.assert_close(next_z.view(4, -1, 8).sum(-1), th.ones(4, 16))
    assert model.reward(z, action).shape == (4, 101)
    assert model.q(z, action).shape == (3, 4, 101)
    # Zero-initialised output layers: reward and Q start at 0.
    th.testing.assert_close(model.reward_value(z, action), th.zeros(4))
    th.testing.assert_close(model.q_value(z, action, reduce="min"), th.zeros(4))
    sample = model.pi(z)
    assert sample.action.shape == sample.mean.shape == (4, 2) and sample.log_prob.shape == (4,)
    assert sample.action.abs().max() <= 1


def test_target_q_follows_online_q_by_polyak_averaging():
    model = make_model()
    assert not any(p.requires_grad for p in model.target_q_heads.parameters())
    with th.no_grad():
        for p in model.q_heads.parameters():
            p.add_(1.0)
    before = [p.clone() for p in model.target_q_heads.parameters()]
    model.soft_update_target_q(0.25)
    for old, new, online in zip(before, model.target_q_heads.parameters(), model.q_heads.parameters(), strict=True):
        th.testing.assert_close(new, 0.75 * old + 0.25 * online)
    model.train()
    assert not model.target_q_heads.training


def test_q_value_rejects_unknown_reduction():
    model = make_model()
    with pytest.raises(ValueError, match="'min' or 'avg'"):
        model.q_value(th.zeros(1, 128), th.zeros(1, 2), reduce="max")
