"""The Distracting Control Suite (Stone et al. 2021) on sb3-ef's DMC pixel envs (no MuJoCo import here)."""

from sb3_ef.envs.distracting.davis import DAVIS_DIR_VARIABLE, DAVIS_TRAIN_VIDEOS, DAVIS_VALIDATION_VIDEOS
from sb3_ef.envs.distracting.settings import DIFFICULTY_SCALES, DIFFICULTY_VIDEOS, DISTRACTIONS

__all__ = [
    "DAVIS_DIR_VARIABLE",
    "DAVIS_TRAIN_VIDEOS",
    "DAVIS_VALIDATION_VIDEOS",
    "DIFFICULTY_SCALES",
    "DIFFICULTY_VIDEOS",
    "DISTRACTIONS",
]
