"""TDMPC2Policy's arguments: DrQ-v2's size arguments are refused with TD-MPC2's equivalent named."""

import numpy as np
import pytest
from gymnasium import spaces

from sb3_ef.tdmpc2.policies import TDMPC2Policy

FRAMES = spaces.Box(0, 255, (9, 64, 64), np.uint8)
ACTIONS = spaces.Box(-1.0, 1.0, (2,), np.float32)


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
