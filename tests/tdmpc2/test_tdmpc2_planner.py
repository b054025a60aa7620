import pytest
import torch as th

from sb3_ef.tdmpc2.planner import MPPIPlanner
from sb3_ef.tdmpc2.world_model import WorldModel


class PointModel:
    """A correct hand-made model: a 1-D point moved by the action, rewarded for being at ``goal``."""

    action_dim = 1

    def __init__(self, goal: float):
        self.goal = goal

    def next(self, z, action):
        return z + action

    def reward_value(self, z, action):
        return -((z + action - self.goal) ** 2).squeeze(-1)

    def pi(self, z):
        return (th.rand(*z.shape[:-1], 1) * 2 - 1,)

    def q_value(self, z, action, reduce="avg", target=False):
        return th.zeros(z.shape[:-1])


def test_mppi_finds_the_best_action_of_a_known_model():
    # From 0, the best 3-step plan to reach 0.6 and stay is (0.6, 0, 0); from 0.5 it starts with 0.1.
    planner = MPPIPlanner(horizon=3, iterations=6, num_samples=256, num_elites=32, num_pi_trajs=8, temperature=0.5)
    z = th.tensor([[0.0], [0.5]])
    action, mean = planner.plan(PointModel(goal=0.6), z, deterministic=True)
    assert mean.shape == (2, 3, 1)
    th.testing.assert_close(action, th.tensor([[0.6], [0.1]]), atol=0.05, rtol=0)
    noisy, _ = planner.plan(PointModel(goal=0.6), z, deterministic=False)
    assert (noisy - th.tensor([[0.6], [0.1]])).abs().max() < 0.5
    assert noisy.abs().max() <= 1


def test_mppi_warm_starts_from_the_previous_plan_shifted():
    # Uniform elite weights and a tiny std: the refit mean is the initial mean, i.e. the shifted previous plan.
    planner = MPPIPlanner(
        horizon=3, iterations=1, num_samples=512, num_elites=512, num_pi_trajs=0, min_std=0.01, max_std=0.01
    )
    planner.temperature = 0.0
    previous = th.tensor([[[0.9], [0.4], [-0.3]]])
    _, mean = planner.plan(PointModel(goal=0.0), th.zeros(1, 1), previous_mean=previous)
    th.testing.assert_close(mean, th.tensor([[[0.4], [-0.3], [0.0]]]), atol=0.005, rtol=0)


def test_mppi_plans_with_a_world_model():
    model = WorldModel(in_channels=9, action_dim=2, num_channels=4, mlp_dim=16, num_q=2).eval()
    planner = MPPIPlanner(iterations=2, num_samples=16, num_elites=4, num_pi_trajs=4)
    z = model.encode(th.randint(0, 256, (3, 9, 64, 64), dtype=th.uint8))
    action, mean = planner.plan(model, z)
    assert action.shape == (3, 2) and mean.shape == (3, 3, 2)
    assert action.abs().max() <= 1


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"num_samples": 8, "num_pi_trajs": 8}, "num_pi_trajs"),
        ({"num_samples": 8, "num_pi_trajs": 2, "num_elites": 9}, "num_elites"),
        ({"min_std": 0.5, "max_std": 0.1}, "min_std"),
        ({"horizon": 0}, "horizon"),
    ],
)
def test_mppi_rejects_bad_sizes(kwargs, match):
    with pytest.raises(ValueError, match=match):
        MPPIPlanner(**kwargs)
