"""TDMPC2Policy's arguments: DrQ-v2's size arguments are refused with TD-MPC2's equivalent named; TD-MPC2's action
space."""

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from sb3_ef.tdmpc2 import TDMPC2
from sb3_ef.tdmpc2.policies import TDMPC2Policy
from tests.helpers.drqv2 import make_cue_env

FRAMES = spaces.Box(0, 255, (9, 64, 64), np.uint8)
ACTIONS = spaces.Box(-1.0, 1.0, (2,), np.float32)
TINY = {"num_channels": 4, "mlp_dim": 32, "num_q": 2}


@pytest.mark.parametrize(
    ("name", "instead"),
    [
        ("net_arch", "its sizes are set by mlp_dim"),
        ("features_dim", "its sizes are set by num_channels"),
        ("normalize_images", "its encoder always scales the uint8 frames itself"),
        ("no_such_size", "its arguments are listed in the TDMPC2Policy docstring"),
    ],
)
def test_drqv2_size_arguments_name_the_tdmpc2_ones(name, instead):
    """The README's DrQv2EF policy_kwargs given to TDMPC2EF: a clear error instead of a bare TypeError."""
    with pytest.raises(ValueError, match=f"TDMPC2Policy has no argument '{name}': {instead}"):
        TDMPC2Policy(FRAMES, ACTIONS, lambda _: 3e-4, num_channels=4, mlp_dim=32, **{name: [256, 256]})


def test_predict_acts_in_the_envs_bounds_as_the_rollouts_do():
    """The same model and plan on an env in [-1, 1] and on the env rescaled to [-2, 3]: the action rescaled."""
    actions = []
    for env in (make_cue_env(size=64), gym.wrappers.RescaleAction(make_cue_env(size=64), -2.0, 3.0)):
        model = TDMPC2("CnnPolicy", env, policy_kwargs=TINY, seed=0, device="cpu")
        observation, _ = env.reset(seed=0)
        actions.append(model.predict(observation, deterministic=True)[0])
    assert np.all(np.abs(actions[0]) <= 1.0)
    np.testing.assert_allclose(actions[1], -2.0 + (actions[0] + 1.0) * 2.5, rtol=1e-5, atol=1e-5)
