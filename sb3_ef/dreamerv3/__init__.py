"""Dreamer-v3 (Hafner et al., 2023) as a baseline: sheeprl's implementation with SB3's interface (docs/dreamerv3.md)."""

from sb3_ef.dreamerv3.callbacks import Evaluation
from sb3_ef.dreamerv3.dreamerv3 import DreamerV3
from sb3_ef.dreamerv3.env import NewestFrame

__all__ = ["DreamerV3", "Evaluation", "NewestFrame"]
