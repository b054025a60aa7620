"""rl-zoo3 plug-in: the registry's algorithms and Optuna samplers (docs/zoo.md), imported on first use."""

from __future__ import annotations

from sb3_ef.common.lazy import lazy_attributes

_PUBLIC = {
    "ZOO_ALGORITHMS": "sb3_ef.zoo.config",
    "default_config_path": "sb3_ef.zoo.config",
    "validate_config": "sb3_ef.zoo.config",
    "register_algorithms": "sb3_ef.zoo.registration",
}

__all__ = list(_PUBLIC)

__getattr__ = lazy_attributes(__name__, _PUBLIC)
