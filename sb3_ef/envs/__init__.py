"""Pixel environments (DMC, Meta-World, Distracting Control) with frame stacking, action repeat and agent masks;
MuJoCo, dm-control and metaworld are imported by ``make_env``, after the OpenGL backend is chosen."""

from sb3_ef.envs.factory import MAX_SIZE, MIN_SIZE, make_env
from sb3_ef.envs.tasks import (
    DISTRACTING_TASKS,
    DMC_PAPER_TASKS,
    DMC_TASKS,
    ENV_NAMES,
    METAWORLD_PAPER_TASKS,
    METAWORLD_TASKS,
)

__all__ = [
    "DISTRACTING_TASKS",
    "DMC_PAPER_TASKS",
    "DMC_TASKS",
    "ENV_NAMES",
    "MAX_SIZE",
    "METAWORLD_PAPER_TASKS",
    "METAWORLD_TASKS",
    "MIN_SIZE",
    "make_env",
]
