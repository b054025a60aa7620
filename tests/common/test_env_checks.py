"""The env and buffer checks shared by the algorithms, their policies and the analysis."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.wrappers import TimeLimit
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_ef.common.env_checks import check_box_actions, check_stacked_frames, episode_steps, sequence_buffer
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


def test_checks_name_expected_and_received():
    with pytest.raises(ValueError, match=r"Host needs windows: .*SequenceReplayBuffer.*got ReplayBuffer"):
        sequence_buffer(ReplayBuffer, {}, "Host needs windows", horizon=3)
    with pytest.raises(ValueError, match=r"Host expects stacked RGB frames.*got Box\(0, 255, \(4, 8, 8\)"):
        check_stacked_frames(spaces.Box(0, 255, (4, 8, 8), np.uint8), "Host")
    with pytest.raises(ValueError, match=r"Host needs a continuous \(Box\) action space, got Discrete\(3\)"):
        check_box_actions(spaces.Discrete(3), "Host")
    assert check_stacked_frames(spaces.Box(0, 255, (9, 8, 16), np.uint8), "Host") == (9, 8, 16)
