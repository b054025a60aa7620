"""The pixel envs pass SB3's env checker with its render check, which resets an env after closing it."""

import numpy as np
import pytest
from stable_baselines3.common.env_checker import check_env

from sb3_ef.envs import make_env


@pytest.mark.parametrize("name", ["dmc/reacher-easy", "metaworld/reach"])
@pytest.mark.parametrize("render_mode", [None, "rgb_array"])
def test_sb3_check_env_with_its_render_check(name, render_mode):
    env = make_env(name, size=32, fast_render=True, render_mode=render_mode)
    try:
        check_env(env, warn=True, skip_render_check=False)
    finally:
        env.close()


def test_an_env_resets_and_steps_after_close_as_before():
    env = make_env("dmc/reacher-easy", size=32, fast_render=True)
    try:
        action = np.full(env.action_space.shape, 0.5, np.float32)
        first, _ = env.reset(seed=3)
        stepped = env.step(action)[0]
        env.close()
        again, _ = env.reset(seed=3)  # a new renderer is opened
        np.testing.assert_array_equal(again, first)
        np.testing.assert_array_equal(env.step(action)[0], stepped)
        assert env.agent_mask().shape == (32, 32)
    finally:
        env.close()
        env.close()  # closing twice is harmless
