"""Pixel environments (DMC, Meta-World, Distracting Control); ``make_env`` imports MuJoCo once a backend is chosen."""

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
