"""Ego-Foresight without RL: robot-video datasets, offline pretraining, open-loop prediction and warm starts.

The public names are imported on first use, so that the command line checks its arguments before torch loads.
``collect``, ``pretrain`` and ``evaluate`` here are the functions, not their modules. See docs/offline.md.
"""

from __future__ import annotations

import sys
import types
from typing import Any

from sb3_ef.common.lazy import lazy_attributes

_PUBLIC = {
    # episodes and readers
    "Episode": "sb3_ef.offline.episodes",
    "EpisodeError": "sb3_ef.offline.episodes",
    "make_episode": "sb3_ef.offline.episodes",
    "read_episode_file": "sb3_ef.offline.episodes",
    "write_episode": "sb3_ef.offline.episodes",
    "EpisodeDataset": "sb3_ef.offline.dataset",
    "FolderDataset": "sb3_ef.offline.readers",
    "MinariDataset": "sb3_ef.offline.readers",
    "BAIRDataset": "sb3_ef.offline.readers",
    "open_dataset": "sb3_ef.offline.readers",
    "load_episodes": "sb3_ef.offline.readers",
    "LeRobotDataset": "sb3_ef.offline.lerobot",
    "LeRobotWriter": "sb3_ef.offline.lerobot_writer",
    "write_lerobot": "sb3_ef.offline.lerobot_writer",
    "RLDSDataset": "sb3_ef.offline.rlds",
    "OXE_LAYOUTS": "sb3_ef.offline.rlds",
    "StreamingWindowSampler": "sb3_ef.offline.streaming",
    # recording, training, prediction, warm start
    "collect": "sb3_ef.offline.collect",
    "record_episode": "sb3_ef.offline.collect",
    "pretrain": "sb3_ef.offline.pretrain",
    "OfflineEF": "sb3_ef.offline.model",
    "OfflineEFConfig": "sb3_ef.offline.model",
    "load_pretrained": "sb3_ef.offline.model",
    "evaluate": "sb3_ef.offline.evaluate",
    "predict_frames": "sb3_ef.offline.predict",
    "predict_episode": "sb3_ef.offline.predict",
    "load_ef": "sb3_ef.offline.warm_start",
    "Interrupted": "sb3_ef.common.interrupt",
}

__all__ = list(_PUBLIC)

__getattr__ = lazy_attributes(__name__, _PUBLIC)


class _Package(types.ModuleType):
    """Keeps ``collect``, ``pretrain`` and ``evaluate`` the functions: the import system would set each loaded
    submodule on its package, hiding the function of the same name."""

    def __setattr__(self, name: str, value: Any) -> None:
        if not (name in _PUBLIC and isinstance(value, types.ModuleType)):
            super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
