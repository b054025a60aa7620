import pytest
import torch as th

from sb3_ef.tdmpc2.math import TwoHot, discount_from_episode_length, symexp, symlog


def test_symexp_inverts_symlog():
    x = th.tensor([-1e4, -12.5, -1.0, -1e-3, 0.0, 1e-3, 0.7, 3.0, 250.0])
    th.testing.assert_close(symexp(symlog(x)), x, rtol=1e-5, atol=1e-6)
    assert symlog(th.tensor(0.0)) == 0


def test_two_hot_round_trip_and_weights():
    two_hot = TwoHot(num_bins=101, vmin=-10, vmax=10)
    x = th.tensor([[-300.0, -2.5, 0.0], [0.3, 7.0, 1000.0]])
    encoded = two_hot.encode(x)
    assert encoded.shape == (2, 3, 101)
    th.testing.assert_close(encoded.sum(-1), th.ones(2, 3))
    assert ((encoded > 0).sum(-1) <= 2).all()
    # Decoding the log of a two-hot vector gives back the scalar (softmax of log p is p).
    th.testing.assert_close(two_hot.decode(encoded.clamp_min(1e-30).log()), x, rtol=1e-4, atol=1e-4)


def test_two_hot_clamps_to_range_ends():
    two_hot = TwoHot(num_bins=5, vmin=-1, vmax=1)
    encoded = two_hot.encode(th.tensor([1e6, -1e6]))
    th.testing.assert_close(encoded, th.tensor([[0.0, 0, 0, 0, 1], [1, 0, 0, 0, 0]]))


def test_cross_entropy_is_smallest_at_the_target():
    two_hot = TwoHot(num_bins=21, vmin=-5, vmax=5)
    target = th.tensor([2.0])
    good = two_hot.encode(target).clamp_min(1e-8).log()
    bad = two_hot.encode(th.tensor([-2.0])).clamp_min(1e-8).log()
    assert two_hot.cross_entropy(good, target) < two_hot.cross_entropy(bad, target)


@pytest.mark.parametrize(("kwargs", "match"), [({"num_bins": 1}, "at least 2 bins"), ({"vmin": 1, "vmax": 0}, "vmin")])
def test_two_hot_rejects_bad_config(kwargs, match):
    with pytest.raises(ValueError, match=match):
        TwoHot(**kwargs)


def test_discount_heuristic():
    assert discount_from_episode_length(500) == pytest.approx(0.99)
    assert discount_from_episode_length(10) == 0.95
    assert discount_from_episode_length(10**6) == 0.995
    with pytest.raises(ValueError, match="positive"):
        discount_from_episode_length(0)
