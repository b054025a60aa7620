"""sb3-ef: Ego-Foresight for Stable-Baselines3 (names imported lazily; importing registers the pixel envs)."""

from __future__ import annotations

import os
from typing import Any

from sb3_ef import (
    _moved,  # noqa: F401  (first: old import paths of the last release say where they went)
    registry,
)
from sb3_ef.common.lazy import lazy_attributes
from sb3_ef.envs.registration import register_envs

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as _file:
    __version__ = _file.read().strip()

_PUBLIC = {
    **{item.class_name: item.module for item in registry.ALGORITHMS.values() if not item.workbench},
    "MotorBabblingCallback": "sb3_ef.ef.babbling",
    "SequenceReplayBuffer": "sb3_ef.common.buffers",
    "make_env": "sb3_ef.envs",
    "export_policy": "sb3_ef.common.export",
}

__all__ = [*_PUBLIC, "__version__"]

register_envs()

_lazy = lazy_attributes(__name__, _PUBLIC)


def __getattr__(name: str) -> Any:
    """A public name, imported now; a workbench class (``DreamerV3``) is refused with the import that gives it."""
    item = registry.by_class_name(name)
    if item is not None and item.workbench:
        raise ImportError(f"sb3_ef does not export {name}, a workbench class: `from {item.module} import {name}`")
    return _lazy(name)
