"""Meta-World with the EF authors' protocol: the per-simulator-step discount inside action repeat and the matching
gamma, checked against discounting written out per simulator step."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.envs import make_env
from sb3_ef.envs.meta_world import authors_gamma

TASK = "metaworld/reach"
STEPS = 4


def rollout(actions: np.ndarray, **kwargs) -> tuple[list[np.ndarray], list[float]]:
    env = make_env(TASK, size=32, fast_render=True, seed=0, **kwargs)
    try:
        observations = [env.reset(seed=0)[0]]
        rewards = []
        for action in actions:
            observation, reward, *_ = env.step(action)
            observations.append(observation)
            rewards.append(reward)
        return observations, rewards
    finally:
        env.close()


@pytest.fixture(scope="module")
def runs():
    """The same seed and actions with the authors' protocol (2 repeats) and with one simulator step per step."""
    actions = np.random.default_rng(0).uniform(-1, 1, (STEPS, 4)).astype(np.float32)
    authors = rollout(actions, repeat_discount=0.99)
    simulator = rollout(np.repeat(actions, 2, axis=0), action_repeat=1)
    return authors, simulator[1]


def test_repeat_discount_weighs_the_second_simulator_step(runs):
    (_, rewards), simulator_rewards = runs
    expected = [simulator_rewards[2 * t] + 0.99 * simulator_rewards[2 * t + 1] for t in range(STEPS)]
    np.testing.assert_allclose(rewards, expected, rtol=1e-6)
    assert not np.allclose(rewards, [simulator_rewards[2 * t] + simulator_rewards[2 * t + 1] for t in range(STEPS)])


def test_effective_discount_of_the_authors_protocol(runs):
    # Their code: 0.99 per simulator step in the action-repeat wrapper (0.9801 per agent step) times 0.99 in the
    # replay buffer: 0.970299 per agent step; a 3-step return bootstraps with 0.970299^3 = 0.99^9 = 0.9135.
    gamma = authors_gamma()
    assert gamma == pytest.approx(0.970299, abs=1e-12)
    (observations, rewards), simulator_rewards = runs
    env = make_env(TASK, size=32, fast_render=True)
    buffer = SequenceReplayBuffer(16, env.observation_space, env.action_space, n_steps=3, gamma=gamma, horizon=3)
    env.close()
    for t in range(STEPS):
        buffer.add(
            observations[t][None],
            observations[t + 1][None],
            np.full((1, 4), t / STEPS),  # the stored action labels the transition with its step
            np.array([rewards[t]]),
            np.array([False]),
            [{}],
        )
    batch = buffer.sample(256)
    at_start = batch.actions[:, 0] == 0.0
    assert at_start.any(), "the transition at t = 0 was never drawn"
    # Simulator step j of agent step t = j // 2 is weighted 0.99^(3t + j % 2): 0.99 per simulator step, and 0.99
    # more at each agent step.
    expected = sum(0.99 ** (3 * (j // 2) + j % 2) * simulator_rewards[j] for j in range(6))
    assert batch.rewards[at_start][0].item() == pytest.approx(expected, rel=1e-5)
    assert batch.discounts[at_start][0].item() == pytest.approx(0.9135172474836408, rel=1e-6)


def test_default_sums_the_repeats_and_bad_values_are_rejected():
    env = make_env(TASK, size=32, fast_render=True)
    assert env.repeat_discount == 1.0
    env.close()
    with pytest.raises(ValueError, match=r"repeat_discount must be a number in \(0, 1\], got 1.5"):
        make_env(TASK, size=32, repeat_discount=1.5)
    with pytest.raises(ValueError, match="Meta-World option"):
        make_env("dmc/cartpole-swingup", size=32, repeat_discount=0.99)
