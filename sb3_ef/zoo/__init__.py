"""rl-zoo3 plug-in: registers ``drqv2_ef``, ``drqv2``, ``tdmpc2_ef``, ``tdmpc2``, ``sac_ef``, ``td3_ef`` and
``tqc_ef`` with their Optuna samplers.

Entry points: ``python -m sb3_ef.zoo.train`` and ``python -m sb3_ef.zoo.enjoy`` (rl-zoo3's arguments), or the
``sb3-ef`` console script. See docs/zoo.md. The public names are imported on first use (rl-zoo3 imports torch), so
that the command line can check its arguments first.
"""

from __future__ import annotations

import importlib
from typing import Any

_PUBLIC = {
    "ZOO_ALGORITHMS": "sb3_ef.zoo.config",
    "default_config_path": "sb3_ef.zoo.config",
    "validate_config": "sb3_ef.zoo.config",
    "register_algorithms": "sb3_ef.zoo.registration",
}

__all__ = list(_PUBLIC)


def __getattr__(name: str) -> Any:
    if name in _PUBLIC:
        return getattr(importlib.import_module(_PUBLIC[name]), name)
    raise AttributeError(f"module 'sb3_ef.zoo' has no attribute {name!r}")
