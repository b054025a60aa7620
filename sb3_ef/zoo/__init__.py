"""rl-zoo3 plug-in: registers the registry's algorithms that rl-zoo3 trains, with their Optuna samplers (docs/zoo.md).
Public names are imported on first use (rl-zoo3 imports torch), so that the command line is checked first."""

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
