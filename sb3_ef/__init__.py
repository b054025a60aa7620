"""sb3-ef: Ego-Foresight for Stable-Baselines3 (names imported lazily; importing registers the pixel envs)."""

from __future__ import annotations

import os

from sb3_ef.common.lazy import lazy_attributes
from sb3_ef.envs.registration import register_envs

with open(os.path.join(os.path.dirname(__file__), "version.txt")) as _file:
    __version__ = _file.read().strip()

_PUBLIC = {
    "DrQv2EF": "sb3_ef.drqv2",
    "DrQv2": "sb3_ef.drqv2",
    "TDMPC2EF": "sb3_ef.tdmpc2",
    "TDMPC2": "sb3_ef.tdmpc2",
    "SACEF": "sb3_ef.sb3_hosts",
    "TD3EF": "sb3_ef.sb3_hosts",
    "TQCEF": "sb3_ef.sb3_hosts",
    "PPOEF": "sb3_ef.sb3_hosts",
    "A2CEF": "sb3_ef.sb3_hosts",
    "SEAR": "sb3_ef.sear",
    "CURL": "sb3_ef.curl",
    "DreamerV3": "sb3_ef.dreamerv3",  # the workbench's sheeprl wrapper, named here lazily: the library never imports it
    "MotorBabblingCallback": "sb3_ef.ef.babbling",
    "SequenceReplayBuffer": "sb3_ef.common.buffers",
    "make_env": "sb3_ef.envs",
}

__all__ = [*_PUBLIC, "__version__"]

register_envs()

__getattr__ = lazy_attributes(__name__, _PUBLIC)
