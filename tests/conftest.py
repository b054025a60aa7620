import os

# Headless MuJoCo rendering; sb3_ef.envs also picks a backend itself when none is set.
os.environ.setdefault("MUJOCO_GL", "egl")

import pytest
import torch as th

th.set_num_threads(1)


@pytest.fixture(autouse=True)
def _seed_torch():
    th.manual_seed(0)
