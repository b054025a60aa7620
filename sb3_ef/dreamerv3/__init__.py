"""Dreamer-v3 (Hafner et al., 2023) as a baseline: sheeprl's implementation, run on sb3-ef's pixel envs.

``DreamerV3`` wraps sheeprl (``pip install -e .[dreamerv3]``) with SB3's learn / predict / save / load; the
benchmark grid runs it as the ``dreamerv3`` row (:mod:`sb3_ef.dreamerv3.grid_run`). sheeprl is imported only when a
model is built, so this package imports without it.
"""

from sb3_ef.dreamerv3.callbacks import Evaluation
from sb3_ef.dreamerv3.dreamerv3 import DreamerV3
from sb3_ef.dreamerv3.env import NewestFrame

__all__ = ["DreamerV3", "Evaluation", "NewestFrame"]
