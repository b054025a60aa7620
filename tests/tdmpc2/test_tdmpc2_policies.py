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


@pytest.mark.parametrize(
    ("name", "instead"),
    [("net_arch", "mlp_dim"), ("features_dim", "num_channels"), ("no_such_size", "TDMPC2Policy docstring")],
)
def test_drqv2_size_arguments_name_the_tdmpc2_ones(name, instead):
    """The README's DrQv2EF policy_kwargs given to TDMPC2EF: a clear error instead of a bare TypeError."""
    with pytest.raises(ValueError, match=f"TDMPC2Policy has no argument '{name}': .*{instead}"):
        TDMPC2Policy(FRAMES, ACTIONS, lambda _: 3e-4, num_channels=4, mlp_dim=32, **{name: [256, 256]})


def test_an_action_space_other_than_minus_one_to_one_is_refused_with_the_wrapper_named():
    env = gym.wrappers.RescaleAction(make_cue_env(size=64), -2.0, 2.0)
    with pytest.raises(ValueError, match=r"TD-MPC2 plans actions in \[-1, 1\]: rescale .*RescaleAction"):
        TDMPC2("CnnPolicy", env)
