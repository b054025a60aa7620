import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from sb3_ef.envs.toy import AGENT_COLOUR, ToyAgentEnv


def test_observations_follow_the_project_contract():
    env = ToyAgentEnv(size=16, frame_stack=3)
    check_env(env, skip_render_check=True)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.shape == (9, 16, 16) and obs.dtype == np.uint8
    assert np.array_equal(obs[:3], obs[6:])  # the first frame repeated at reset
    first = obs[-3:]
    obs, *_ = env.step(np.ones(2, dtype=np.float32))
    assert np.array_equal(obs[3:6], first) and np.array_equal(obs[-3:].transpose(1, 2, 0), env.render())


def test_agent_mask_marks_the_red_square_which_moves_with_the_actions():
    env = ToyAgentEnv(size=32, distractor=False)
    env.reset(seed=1)
    env._agent[:] = 10.0  # away from the borders
    obs, *_ = env.step(np.array([1.0, -0.5]))
    assert np.allclose(env.agent_position, [10 + env.speed, 10 - 0.5 * env.speed])
    red = np.all(obs[-3:].transpose(1, 2, 0) == AGENT_COLOUR, axis=-1)
    assert np.array_equal(red, env.agent_mask()) and red.sum() == env.square**2
    assert np.array_equal(np.argwhere(red).min(axis=0), np.rint(env.agent_position))


def test_distractor_ignores_the_actions():
    trajectories = []
    for action in (np.ones(2), -np.ones(2)):
        env = ToyAgentEnv(size=32)
        env.reset(seed=3)
        trajectories.append([env.step(action) and env.distractor_position for _ in range(10)])
    assert np.array_equal(trajectories[0], trajectories[1])
    assert len({tuple(position) for position in trajectories[0]}) > 1  # it does move


def test_episodes_are_truncated():
    env = ToyAgentEnv(size=16, max_episode_steps=3)
    env.reset(seed=0)
    flags = [env.step(np.zeros(2))[2:4] for _ in range(3)]
    assert flags == [(False, False), (False, False), (False, True)]


def test_bad_arguments_are_rejected():
    with pytest.raises(ValueError, match="size"):
        ToyAgentEnv(size=4)
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        env = ToyAgentEnv(size=16)
        env.reset(seed=0)
        env.step(np.zeros(3))
