"""Dreamer-v3 (Hafner et al., 2023) as a baseline: sheeprl's implementation (``pip install -e .[dreamerv3]``,
imported only when a model is built) with SB3's learn / predict / save / load, on sb3-ef's pixel envs."""

from sb3_ef.dreamerv3.callbacks import Evaluation
from sb3_ef.dreamerv3.dreamerv3 import DreamerV3
from sb3_ef.dreamerv3.env import NewestFrame

__all__ = ["DreamerV3", "Evaluation", "NewestFrame"]
