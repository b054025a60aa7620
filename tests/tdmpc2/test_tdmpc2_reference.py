"""TDMPC2 against the reference (nicklashansen/tdmpc2): numbers derived here from its equations and defaults.

The seed actions and the seed-data burst, the heuristics (seed steps, discount, MPPI iterations), the policy's
entropy term, the TD target, the evaluation action, the warm start in evaluation and the gradient clip.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF
from sb3_ef.tdmpc2.gradients import clipped_world_model_gradients
from sb3_ef.tdmpc2.math import planning_iterations, seed_steps_from_episode_length
from sb3_ef.tdmpc2.planner import MPPIPlanner
from sb3_ef.tdmpc2.policies import TDMPC2Policy
from tests.helpers.tdmpc2 import TINY_POLICY, host_loss, tiny_policy


def learning_rate(_progress_remaining: float) -> float:
    return 3e-4


def make(algorithm=TDMPC2, episode_steps: int = 20, **kwargs):
    arguments = {"learning_starts": 10, "batch_size": 4, "buffer_size": 300, "seed": 0}
    arguments["policy_kwargs"] = tiny_policy(algorithm)
    if algorithm is TDMPC2EF:
        arguments.update(ef_horizon=5, babbling_steps=0)
    arguments.update(kwargs)
    return algorithm("CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=episode_steps), **arguments)


def add_episode(model, rewards: list[float]) -> None:
    """Store one hand-made episode: frame ``t`` is filled with the value ``t``, the reward of step ``t`` is
    ``rewards[t]``, so that a sampled observation tells which step it is."""
    buffer = model.replay_buffer
    frames = [np.full((1, 3, 64, 64), t, dtype=np.uint8) for t in range(len(rewards) + 1)]

    def stack(t: int) -> np.ndarray:
        return np.concatenate([frames[max(i, 0)] for i in range(t - 2, t + 1)], axis=1)

    for t, reward in enumerate(rewards):
        last = t == len(rewards) - 1
        buffer.add(stack(t), stack(t + 1), np.zeros((1, 2)), np.array([reward]), np.array([last]), [{}])


# Seed steps and the burst of updates when they end.


def test_seed_steps_heuristic():
    # max(1000, 5 x episode length): DMC (1000 simulator steps at action repeat 2), Meta-World (500 at 2), short.
    assert seed_steps_from_episode_length(500) == 2500
    assert seed_steps_from_episode_length(250) == 1250
    assert seed_steps_from_episode_length(20) == 1000
    with pytest.raises(ValueError, match="positive"):
        seed_steps_from_episode_length(0)


def test_learning_starts_defaults_to_the_heuristic_and_keeps_a_given_value():
    assert make(learning_starts=None).learning_starts == 1000  # 20-step episodes
    assert make(learning_starts=None, episode_steps=300).learning_starts == 1500
    assert make(learning_starts=7).learning_starts == 7


def test_seed_steps_need_a_known_episode_length():
    env = ToyAgentEnv(size=64)
    del env.max_episode_steps
    with pytest.raises(ValueError, match="pass learning_starts"):
        TDMPC2("CnnPolicy", env, gamma=0.99, buffer_size=300, policy_kwargs=TINY_POLICY)


@pytest.mark.parametrize("algorithm", [TDMPC2, TDMPC2EF])
def test_seed_data_burst_then_one_update_per_step(algorithm):
    # The reference acts randomly for its seed steps S and, at step S, runs S updates at once, then one per step:
    # after T env steps (T > S) it has run T - 1 updates.
    seed_steps = 10
    model = make(algorithm, learning_starts=seed_steps)
    model.learn(seed_steps)
    assert model._n_updates == 0
    model.learn(1, reset_num_timesteps=False)
    assert model._n_updates == seed_steps
    model.learn(4, reset_num_timesteps=False)
    assert (model.num_timesteps, model._n_updates) == (15, 14)


@pytest.mark.parametrize("algorithm", [TDMPC2, TDMPC2EF])
def test_seed_actions_are_steps_0_to_S_and_the_first_plan_follows_the_burst(algorithm, monkeypatch):
    # The reference acts randomly at its steps 0..S (S + 1 actions: `step > seed_steps` plans) and runs the burst
    # at step S, after that step's action: its first planned action comes from the model trained on the seed data.
    seed_steps = 10
    model = make(algorithm, learning_starts=seed_steps)
    plan, calls = model.policy.plan, []

    def recording_plan(*args, **kwargs):
        calls.append((model.num_timesteps, model._n_updates))
        return plan(*args, **kwargs)

    monkeypatch.setattr(model.policy, "plan", recording_plan)
    model.learn(seed_steps + 1)
    assert (calls, model._n_updates) == ([], seed_steps)
    model.learn(2, reset_num_timesteps=False)
    # (steps taken before the planned action, updates run by then)
    assert calls == [(seed_steps + 1, seed_steps), (seed_steps + 2, seed_steps + 1)]


def test_without_the_burst_one_update_per_step_after_the_seed_steps():
    model = make(learning_starts=10, seed_burst=False)
    model.learn(15)
    assert model._n_updates == 5


# MPPI iterations.


def test_two_more_planning_iterations_for_large_action_spaces():
    assert planning_iterations(19) == 6
    assert planning_iterations(20) == 8  # e.g. humanoid (21), dog (38)
    observation_space = spaces.Box(0, 255, (9, 64, 64), np.uint8)
    policy_kwargs = {"num_channels": 4, "mlp_dim": 16, "num_q": 2}
    for action_dim, iterations in ((6, 6), (21, 8)):
        action_space = spaces.Box(-1, 1, (action_dim,), np.float32)
        policy = TDMPC2Policy(observation_space, action_space, learning_rate, **policy_kwargs)
        assert policy.planner.iterations == iterations


def test_the_two_iterations_are_added_to_a_given_value_too():
    # The reference adds them to its configured `iterations` (`cfg.iterations += 2 * (action_dim >= 20)`).
    assert (planning_iterations(6, 3), planning_iterations(21, 3)) == (3, 5)
    observation_space = spaces.Box(0, 255, (9, 64, 64), np.uint8)
    policy_kwargs = {"num_channels": 4, "mlp_dim": 16, "num_q": 2, "planner_kwargs": {"iterations": 3}}
    for action_dim, iterations in ((6, 3), (21, 5)):
        action_space = spaces.Box(-1, 1, (action_dim,), np.float32)
        policy = TDMPC2Policy(observation_space, action_space, learning_rate, **policy_kwargs)
        assert policy.planner.iterations == iterations
        # Saved with the value given, so that a loaded policy adds them once.
        assert policy._get_constructor_parameters()["planner_kwargs"] == {"iterations": 3}
        assert TDMPC2Policy(**policy._get_constructor_parameters()).planner.iterations == iterations
    for bad in (0, 2.5):
        with pytest.raises(ValueError, match=f"iterations must be a positive integer, got {bad}"):
            TDMPC2Policy(
                observation_space,
                action_space,
                learning_rate,
                **{**policy_kwargs, "planner_kwargs": {"iterations": bad}},
            )


# The policy prior's entropy term.


def fix_policy_output(model, mean: list[float], std: list[float]) -> None:
    """Make the policy prior output the same Gaussian (pre-tanh ``mean``, ``std``) for every latent."""
    world_model = model.world_model
    log_std = th.log(th.tensor(std))
    # log_std = min + (max - min) * (tanh(x) + 1) / 2, solved for the output x.
    span = world_model.log_std_max - world_model.log_std_min
    raw_log_std = th.atanh(2 * (log_std - world_model.log_std_min) / span - 1)
    last = world_model.pi_head[-1]
    with th.no_grad():
        last.weight.zero_()
        last.bias.copy_(th.cat([th.tensor(mean), raw_log_std]))


def test_entropy_term_is_the_scaled_gaussian_log_prob_on_a_fixed_policy_output():
    model = make(entropy_coef=1.0, rho=0.5)
    fix_policy_output(model, mean=[0.3, -0.4], std=[0.5, 2.0])
    latents = model.encode(th.zeros(5, 9, 64, 64, dtype=th.uint8)).detach().view(1, 5, -1).expand(4, 5, -1)
    valid = th.ones(4, 5)

    th.manual_seed(3)
    noise = th.randn(4, 5, 2)
    # Reference: -action_dim x sum_i (-eps_i^2 / 2 - log std_i - log(2 pi) / 2); the tanh correction stays out.
    gaussian_log_prob = (-0.5 * noise.pow(2) - th.log(th.tensor([0.5, 2.0])) - 0.5 * math.log(2 * math.pi)).sum(-1)
    scaled_entropy = -2 * gaussian_log_prob
    # Q is 0 (zero-initialised heads) and its scale 1, so the loss is the rho-weighted mean of the entropy term.
    expected = -(0.5 ** th.arange(4.0) * scaled_entropy.mean(-1)).mean()

    th.manual_seed(3)
    sample = model.world_model.pi(latents)
    th.testing.assert_close(sample.scaled_entropy, scaled_entropy)
    th.manual_seed(3)
    pi_loss = model._policy_loss(latents, valid)
    th.testing.assert_close(pi_loss, expected)
    # The previous choice (the squashed log-prob, tanh correction included, times action_dim) is far from it.
    squashed = -(0.5 ** th.arange(4.0) * (-2 * sample.log_prob).mean(-1)).mean()
    assert (squashed - expected).abs() > 1.0


# TD target.


def constant_q_heads(model, values: list[float], target: bool) -> None:
    """Make each (target) Q head return its value of ``values`` for every input (two-hot logits as its bias)."""
    world_model = model.world_model
    heads = world_model.target_q_heads if target else world_model.q_heads
    for head, value in zip(heads, values, strict=True):
        with th.no_grad():
            head[-1].weight.zero_()
            head[-1].bias.copy_(world_model.two_hot.encode(th.tensor(value)).clamp_min(1e-30).log())


def test_td_target_on_a_hand_made_batch():
    # TD-MPC2: target_i = r_{t+i} + gamma * min(two random target heads)(z_{t+i+1}, pi(z_{t+i+1})), one step each.
    model = make(gamma=0.9)
    rewards = [float(t) for t in range(1, 13)]
    add_episode(model, rewards)
    constant_q_heads(model, [3.0, 5.0], target=True)
    two_hot, targets = model.world_model.two_hot, []
    cross_entropy = two_hot.cross_entropy

    def recording_cross_entropy(logits, target):
        targets.append(target)
        return cross_entropy(logits, target)

    two_hot.cross_entropy = recording_cross_entropy
    batch = model.replay_buffer.sample(8)
    model.losses(batch)
    td_targets = targets[-1][0]  # the value loss's targets, (H, B), repeated for each Q head
    steps = batch.observations[:, -1, 0, 0].long()  # frame t is filled with t
    assert (steps + 2 < len(rewards)).any()
    for i in range(3):
        valid = steps + i < len(rewards)
        expected = th.tensor(rewards)[(steps + i)[valid]] + 0.9 * 3.0
        th.testing.assert_close(td_targets[i][valid], expected, rtol=1e-4, atol=1e-4)


def test_discount_follows_the_episode_length():
    assert make(gamma=None, episode_steps=500).gamma == pytest.approx(0.99)  # (100 - 1) / 100
    assert make(gamma=None, episode_steps=250).gamma == pytest.approx(0.98)  # (50 - 1) / 50


# Evaluation action.


class TwoProposalModel:
    """A hand-made model: only the first action is rewarded, ``-(a - 0.6)^2``; the policy prior proposes
    0.6 and 0.5 as its two trajectories (and 0 elsewhere); Q is 0."""

    action_dim = 1

    def next(self, z, action):
        return z + 1

    def reward_value(self, z, action):
        return -((action - 0.6) ** 2).squeeze(-1) * (z == 0).squeeze(-1)

    def pi(self, z):
        action = th.zeros(*z.shape[:-1], 1)
        if z.shape[-2] == 2:  # the prior's two trajectories
            action[..., 0, :], action[..., 1, :] = 0.6, 0.5
        return (action,)

    def q_value(self, z, action, reduce="avg", target=False):
        return th.zeros(z.shape[:-1])


def test_evaluation_action_is_one_elite_drawn_by_score_without_noise():
    # One iteration: the Gaussian samples (mean 0, std 0.05) score about -0.36, so the 2 elites are the prior's
    # trajectories with values 0 and -0.01. Temperature 100: weights 1 and e^-1, so the first action is 0.6 with
    # probability 1 / (1 + e^-1) = 0.7311 and 0.5 otherwise; the MPPI mean is (0.6 + 0.5 e^-1) / (1 + e^-1).
    planner = MPPIPlanner(
        horizon=3, iterations=1, num_samples=8, num_elites=2, num_pi_trajs=2, min_std=0.05, max_std=0.05
    )
    planner.temperature = 100.0
    z = th.zeros(4000, 1)
    th.manual_seed(0)
    actions, mean = planner.plan(TwoProposalModel(), z, deterministic=True)
    first, second = th.isclose(actions, th.tensor(0.6)), th.isclose(actions, th.tensor(0.5))
    assert (first | second).all()  # an elite's own first action: no noise, no averaging
    share = first.float().mean().item()
    assert share == pytest.approx(1 / (1 + math.exp(-1)), abs=0.03)  # 4 standard errors
    expected_mean = (0.6 + 0.5 * math.exp(-1)) / (1 + math.exp(-1))
    th.testing.assert_close(mean[:, 0], th.full((4000, 1), expected_mean))

    planner.eval_action = "mean"
    actions, _ = planner.plan(TwoProposalModel(), z, deterministic=True)
    th.testing.assert_close(actions, th.full((4000, 1), expected_mean))

    noisy, _ = planner.plan(TwoProposalModel(), z, deterministic=False)  # plus the final std (0.05) as noise
    residual = th.minimum((noisy - 0.6).abs(), (noisy - 0.5).abs())
    assert residual.max() > 0 and residual.mean() < 0.05


def test_predict_deterministic_uses_the_evaluation_action():
    model = make()
    assert model.policy.planner.eval_action == "elite"
    assert make(policy_kwargs={**TINY_POLICY, "planner_kwargs": {"eval_action": "mean"}}).policy.planner.eval_action
    with pytest.raises(ValueError, match="eval_action"):
        MPPIPlanner(eval_action="median")


# Warm start in evaluation.


def test_evaluate_policy_warm_starts_within_each_episode(monkeypatch):
    # The reference's evaluation plans with `t0=t==0`: a zero mean at each episode's first step, then the previous
    # step's final mean (its `_prev_mean`). SB3's evaluate_policy passes predict's state and episode_start.
    model = make().learn(12)
    planner, calls = model.policy.planner, []
    original_plan = planner.plan

    def recording_plan(world_model, z, previous_mean=None, deterministic=False):
        actions, mean = original_plan(world_model, z, previous_mean, deterministic)
        calls.append((None if previous_mean is None else previous_mean.clone(), mean.clone()))
        return actions, mean

    monkeypatch.setattr(planner, "plan", recording_plan)
    env = DummyVecEnv([lambda: Monitor(ToyAgentEnv(size=64, max_episode_steps=4))])
    evaluate_policy(model, env, n_eval_episodes=2, deterministic=True)
    assert len(calls) == 8
    for step, (previous, _) in enumerate(calls):
        if step % 4 == 0:  # an episode's first step
            assert previous is None or bool((previous == 0).all())
        else:
            th.testing.assert_close(previous, calls[step - 1][1], rtol=0, atol=0)


# Gradient clipping.


def clipped(gradients: list[th.Tensor], max_norm: float) -> list[th.Tensor]:
    norm = th.linalg.vector_norm(th.stack([th.linalg.vector_norm(g) for g in gradients]))
    return [g * min(1.0, max_norm / (norm.item() + 1e-6)) for g in gradients]


def host_parameters(model) -> list[th.nn.Parameter]:
    world_model = model.world_model
    modules = (world_model.encoder, world_model.dynamics, world_model.reward_head, world_model.q_heads)
    return [param for module in modules for param in module.parameters()]


@pytest.mark.parametrize("algorithm", [TDMPC2, TDMPC2EF])
def test_one_global_clip_over_the_world_model_for_the_host(algorithm):
    # Reference: clip_grad_norm_(world model, 20) on the host loss's gradient. With EF, its gradient is clipped on
    # its own (over encoder and EF) and added, so the dynamics, reward and Q heads get exactly the host's clip.
    max_norm = 0.05
    model = make(algorithm, max_grad_norm=max_norm)
    add_episode(model, [float(t % 3) for t in range(15)])
    batch = model.replay_buffer.sample(8)
    model.policy.set_training_mode(True)

    th.manual_seed(1)
    losses, _, _, _ = model.losses(batch)
    parameters = host_parameters(model)
    host_gradients = th.autograd.grad(host_loss(model, losses), parameters, retain_graph=True)
    expected_host = clipped(list(host_gradients), max_norm)

    th.manual_seed(1)
    losses, auxiliary, _, _ = model.losses(batch)
    model.policy.optimizer.zero_grad()
    norms = clipped_world_model_gradients(
        model.policy.optimizer, host_loss(model, losses), None if auxiliary is None else auxiliary[0], max_norm
    )
    assert norms["grad_norm"] > max_norm  # the clip is active
    encoder = len(list(model.world_model.encoder.parameters()))
    for param, expected in zip(parameters[encoder:], expected_host[encoder:], strict=True):
        th.testing.assert_close(param.grad, expected)
    if algorithm is TDMPC2:
        for param, expected in zip(parameters[:encoder], expected_host[:encoder], strict=True):
            th.testing.assert_close(param.grad, expected)
    else:
        assert norms["auxiliary_grad_norm"] > max_norm
        ef_gradients = [param.grad for param in model.ef.parameters()]
        encoder_ef = [
            param.grad - expected for param, expected in zip(parameters[:encoder], expected_host[:encoder], strict=True)
        ]
        total = th.linalg.vector_norm(th.stack([th.linalg.vector_norm(g) for g in ef_gradients + encoder_ef]))
        assert total.item() == pytest.approx(max_norm, rel=1e-3)
