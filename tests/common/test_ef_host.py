"""The plumbing both EF hosts share: episode lengths, argument checks, babbling at learn, TensorBoard names."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.common.ef_host import (
    check_ef_arguments,
    check_horizon_fits_episodes,
    check_sequence_buffer,
    check_stacked_frames,
    episode_steps,
)
from sb3_ef.envs.toy import ToyAgentEnv


class _Blank(gym.Env):
    observation_space = spaces.Box(0, 255, (3, 8, 8), np.uint8)
    action_space = spaces.Box(-1, 1, (1,), np.float32)


class _Repeated(_Blank):
    episode_length = 1000
    action_repeat = 3


def _vec(env: gym.Env) -> DummyVecEnv:
    return DummyVecEnv([lambda: env])


@pytest.mark.parametrize(
    ("env", "expected"),
    [
        (TimeLimit(_Blank(), max_episode_steps=7), 7),
        (_Repeated(), 334),  # 1000 simulator steps at action repeat 3: the last agent step is a partial repeat
        (ToyAgentEnv(size=16, max_episode_steps=9), 9),
        (_Blank(), None),
    ],
)
def test_episode_steps_from_each_source(env, expected):
    assert episode_steps(_vec(env)) == expected


def test_horizon_check():
    check_horizon_fits_episodes(10, 10)
    check_horizon_fits_episodes(10, None)
    check_horizon_fits_episodes(None, 3)
    with pytest.raises(ValueError, match="expected ef_horizon <= 9, got 10"):
        check_horizon_fits_episodes(10, 9)


def test_argument_checks_name_expected_and_received():
    with pytest.raises(ValueError, match=r"use Plain to train without Ego-Foresight\), got -1"):
        check_ef_arguments(-1, 10, 0, plain_variant="Plain")
    with pytest.raises(ValueError, match="babbling_steps must be >= 0, got -5"):
        check_ef_arguments(1.0, 10, -5, plain_variant="Plain")
    with pytest.raises(ValueError, match=r"Host needs windows: .*SequenceReplayBuffer.*got ReplayBuffer"):
        check_sequence_buffer(ReplayBuffer, "Host needs windows")
    with pytest.raises(ValueError, match=r"Host expects stacked RGB frames.*got Box\(0, 255, \(4, 8, 8\)"):
        check_stacked_frames(spaces.Box(0, 255, (4, 8, 8), np.uint8), "Host")


def test_plain_and_ef_hosts_log_under_their_own_class_names(tmp_path):
    from sb3_ef import DrQv2, DrQv2EF

    small = {"net_arch": [8], "trunk_dim": 8}
    variants = [
        (DrQv2, {"policy_kwargs": small}),
        (DrQv2EF, {"policy_kwargs": {**small, "features_dim": 16, "agent_dim": 4}, "ef_horizon": 2}),
    ]
    for algorithm, kwargs in variants:
        env = ToyAgentEnv(size=32, max_episode_steps=8)
        model = algorithm(
            "CnnPolicy", env, buffer_size=100, learning_starts=4, batch_size=4, tensorboard_log=str(tmp_path), **kwargs
        )
        model.learn(8)
    assert sorted(path.name for path in tmp_path.iterdir()) == ["DrQv2EF_1", "DrQv2_1"]
