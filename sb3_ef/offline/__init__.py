"""Ego-Foresight without RL: robot-video datasets, offline pretraining, open-loop prediction and warm starts (names
imported on first use, so the CLI checks its arguments before torch loads); see docs/offline.md."""

from __future__ import annotations

import sys
import types
from typing import Any

from sb3_ef.common.lazy import lazy_attributes

_NAMES = {
    "offline.episodes": ("Episode", "EpisodeError", "make_episode", "read_episode_file", "write_episode"),
    "offline.dataset": ("EpisodeDataset",),
    "offline.readers": ("FolderDataset", "MinariDataset", "BAIRDataset", "open_dataset", "load_episodes"),
    "offline.lerobot": ("LeRobotDataset",),
    "offline.lerobot_writer": ("LeRobotWriter", "write_lerobot"),
    "offline.rlds": ("RLDSDataset", "OXE_LAYOUTS"),
    "offline.streaming": ("StreamingWindowSampler",),
    "offline.collect": ("collect", "record_episode"),
    "offline.pretrain": ("pretrain",),
    "offline.model": ("OfflineEF", "OfflineEFConfig", "load_pretrained"),
    "offline.evaluate": ("evaluate",),
    "offline.predict": ("predict_frames", "predict_episode"),
    "offline.warm_start": ("load_ef",),
    "common.interrupt": ("Interrupted",),
}
_PUBLIC = {name: f"sb3_ef.{module}" for module, names in _NAMES.items() for name in names}

__all__ = list(_PUBLIC)

__getattr__ = lazy_attributes(__name__, _PUBLIC)


class _Package(types.ModuleType):
    """Keeps ``collect``, ``pretrain`` and ``evaluate`` the functions, not the submodules the import system sets."""

    def __setattr__(self, name: str, value: Any) -> None:
        if not (name in _PUBLIC and isinstance(value, types.ModuleType)):
            super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
