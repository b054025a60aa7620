"""Where the modules and names that moved or left the package in the last release went: importing an old path
raises an ``ImportError`` that says so. Importing this module puts its finder first on ``sys.meta_path``. Kept for one
release, then deleted with its import in ``sb3_ef/__init__.py``."""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import sys
from collections.abc import Sequence
from types import ModuleType
from typing import Any

_REPOSITORY = "in the sb3-ef repository"
_STUDY = "left the package: the body-schema study's experiments/2026-12-body-schema/{} " + _REPOSITORY
#: Old module -> where it went.
MOVED_MODULES = {
    "sb3_ef.analysis.body_schema": _STUDY.format("body_schema.py"),
    "sb3_ef.analysis.scripted": _STUDY.format("scripted.py"),
    "sb3_ef.envs.geom_masks": _STUDY.format("geom_masks.py"),
    "sb3_ef.dreamerv3.timing": f"left the package: its loop timing is benchmarks/dreamer_timing.py {_REPOSITORY}",
    "sb3_ef.offline.shards": "was merged into sb3_ef.offline.tfrecord (ExampleShards, record_offsets, read_record_at)",
    "sb3_ef.offline.interrupt": "moved to sb3_ef.common.interrupt (Interrupted; the sb3-ef script prints the line)",
    "sb3_ef.auxiliary.step": "moved to sb3_ef.sb3_hosts.step (AuxiliaryStepMixin, also sb3_ef.sb3_hosts')",
    "sb3_ef.zoo.sheeprl_run": "moved to sb3_ef.dreamerv3.zoo_run (Dreamer-v3's train and enjoy in rl-zoo3's folders)",
}
#: Old name in a module that remains -> where it went.
MOVED_NAMES = {
    "sb3_ef.common.augmentation.augment_frames": "moved to sb3_ef.common.buffers.shifted.augment_frames",
    "sb3_ef.ef.latent.latent_window_losses": "moved to sb3_ef.ef.probe.latent_window_losses",
    "sb3_ef.common.buffers.sb3_arrays.step_array": "is sb3_ef.common.buffers.sb3_arrays.step_array_property",
    "sb3_ef.offline.tfrecord.serialize_example": (
        f"left the package (it wrote test fixtures): tests/offline/examples.py {_REPOSITORY}"
    ),
    "sb3_ef.auxiliary.AuxiliaryStepMixin": "moved to sb3_ef.sb3_hosts.AuxiliaryStepMixin (an SB3 off-policy host's)",
    "sb3_ef.ef.foresight.ForesightLoss": "moved to sb3_ef.ef.losses.ForesightLoss (also sb3_ef.ef.ForesightLoss)",
    "sb3_ef.ef.foresight.ForesightTargets": "moved to sb3_ef.ef.losses.ForesightTargets",
    "sb3_ef.ef.foresight.momentum_target": "left the package: sb3_ef.ef.foresight_loss builds latent EF and its target",
    "sb3_ef.ef.latent.check_target": "left the package: sb3_ef.ef.check_ef_kwargs checks ef_kwargs",
}
_MODULES_WITH_MOVED_NAMES = {path.rpartition(".")[0] for path in MOVED_NAMES}


def _moved(path: str, where: str) -> ImportError:
    """An ``ImportError``, not ``ModuleNotFoundError`` or ``AttributeError``: ``from x import y`` replaces those by its
    own message."""
    return ImportError(f"{path} {where}", name=path)


class _WithMovedNames(importlib.abc.Loader):
    """A module's own loader, then a module ``__getattr__`` that names where its moved names went."""

    def __init__(self, loader: Any):
        self.loader = loader

    def __getattr__(self, name: str) -> Any:  # get_source, get_filename, ...: the module's own loader's
        return getattr(self.loader, name)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> ModuleType | None:
        return self.loader.create_module(spec)

    def exec_module(self, module: ModuleType) -> None:
        self.loader.exec_module(module)

        def moved_attribute(name: str) -> Any:  # (none of these modules has a __getattr__ of its own)
            path = f"{module.__name__}.{name}"
            if path in MOVED_NAMES:
                raise _moved(path, MOVED_NAMES[path])
            raise AttributeError(f"module {module.__name__!r} has no attribute {name!r}")

        module.__getattr__ = moved_attribute  # type: ignore[method-assign]


class MovedPathFinder(importlib.abc.MetaPathFinder):
    """First on ``sys.meta_path``: refuses the modules of :data:`MOVED_MODULES` and loads those holding names of
    :data:`MOVED_NAMES` through :class:`_WithMovedNames`; any other import passes by."""

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname in MOVED_MODULES:
            raise _moved(fullname, MOVED_MODULES[fullname])
        if fullname not in _MODULES_WITH_MOVED_NAMES:
            return None
        spec = importlib.machinery.PathFinder.find_spec(fullname, path, target)
        if spec is not None:
            spec.loader = _WithMovedNames(spec.loader)
        return spec


sys.meta_path.insert(0, MovedPathFinder())  # on import: sb3_ef/__init__.py imports this module first
