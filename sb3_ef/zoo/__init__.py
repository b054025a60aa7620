"""rl-zoo3 plug-in: registers ``drqv2_ef``, ``drqv2``, ``tdmpc2_ef`` and ``tdmpc2`` with their Optuna samplers.

Entry points: ``python -m sb3_ef.zoo.train`` and ``python -m sb3_ef.zoo.enjoy`` (rl-zoo3's arguments), or the
``sb3-ef`` console script. See docs/zoo.md.
"""

from sb3_ef.zoo.config import ZOO_ALGORITHMS, default_config_path, validate_config
from sb3_ef.zoo.registration import register_algorithms

__all__ = ["ZOO_ALGORITHMS", "default_config_path", "register_algorithms", "validate_config"]
