"""What Dreamer-v3 reads of an sb3-ef env (the newest frame), and the envs and arguments refused before sheeprl
runs; these tests need no sheeprl."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from sb3_ef.dreamerv3 import NewestFrame
from sb3_ef.dreamerv3.config import Recipe
from sb3_ef.dreamerv3.player import env_actions
from sb3_ef.envs.toy import ToyAgentEnv


def test_the_newest_rgb_frame_of_the_stack_is_what_dreamer_reads():
    stacked = ToyAgentEnv(size=32, frame_stack=3, max_episode_steps=5)
    newest = NewestFrame(ToyAgentEnv(size=32, frame_stack=3, max_episode_steps=5))
    assert newest.observation_space == gym.spaces.Box(0, 255, (3, 32, 32), np.uint8)
    full, _ = stacked.reset(seed=3)
    frame, _ = newest.reset(seed=3)
    np.testing.assert_array_equal(frame, full[-3:])
    for _ in range(5):
        action = np.array([0.7, -0.4], dtype=np.float32)
        full, reward, terminated, truncated, _ = stacked.step(action)
        frame, reward_, terminated_, truncated_, _ = newest.step(action)
        np.testing.assert_array_equal(frame, full[-3:])
        assert (reward, terminated, truncated) == (reward_, terminated_, truncated_)
    assert truncated  # the time limit passes through
    assert not np.array_equal(full[-3:], full[:3])  # the newest frame is not the oldest


@pytest.mark.parametrize(
    ("env", "message"),
    [
        (ToyAgentEnv(size=24), "power of 2.*24x24"),
        (gym.make("CartPole-v1"), "stacked RGB frames"),
    ],
)
def test_envs_dreamer_cannot_read_are_refused(env, message):
    with pytest.raises(ValueError, match=message):
        NewestFrame(env)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"model_size": "XXL"}, "model_size must be one of"),
        ({"replay_ratio": 0}, "replay_ratio must be > 0"),
        ({"batch_size": 0}, "batch_size must be an integer >= 1"),
        ({"sequence_length": 64, "buffer_size": 10}, "must hold one sequence"),
        ({"learning_starts": -1}, "learning_starts must be an integer >= 0"),
        ({"sheeprl_overrides": {"env.screen_size": 32}}, "'env.screen_size' is set by DreamerV3 from env"),
        ({"sheeprl_overrides": {"algo.per_rank_batch_size": 2}}, "from batch_size"),
        ({"sheeprl_overrides": {"fabric.accelerator": "cuda"}}, "from device"),
        ({"sheeprl_overrides": {"env": {"screen_size": 32}}}, "'env.screen_size' is set by DreamerV3 from env"),
        ({"sheeprl_overrides": ["algo.horizon"]}, r"must be a dict of sheeprl's keys to values, dotted .* \(list\)"),
        ({"sheeprl_overrides": {"algo": {1: 2}}}, r"nested \(\{'algo': \{'horizon': 15\}\}\), got the key 1 \(int\)"),
    ],
)
def test_bad_settings_are_refused_naming_what_was_expected(kwargs, message):
    with pytest.raises(ValueError, match=message):
        Recipe(**kwargs)


class _BoundedActions(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (3, 8, 8), np.uint8)
    action_space = gym.spaces.Box(np.array([-1, 0, -2], np.float32), np.array([1, 4, 2], np.float32))


def test_actor_actions_are_rescaled_to_the_env_bounds_as_sheeprl_does():
    wrappers = pytest.importorskip("sheeprl.envs.wrappers")
    env = _BoundedActions()
    normalized = wrappers.NormalizeAction(env)
    actions = np.array([[0.5, -1.0, 0.25], [2.0, 0.5, -3.0]], dtype=np.float32)
    expected = [normalized.action(row) for row in actions]
    np.testing.assert_array_equal(env_actions(actions, env.action_space, normalize=True), expected)
    np.testing.assert_allclose(expected, [[0.5, 0.0, 0.5], [1.0, 3.0, -2.0]])
    np.testing.assert_array_equal(env_actions(actions, env.action_space, normalize=False), actions)
