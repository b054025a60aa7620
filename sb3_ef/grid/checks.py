"""The checks of a grid's rows before anything trains: each row's env and algorithm built short of networks."""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

from sb3_ef.grid.grid import RunSpec, algorithm_class
from sb3_ef.grid.run import RunPaths, build_training_env, new_model, read_result
from sb3_ef.registry import import_target

#: Errors of a row's check reported by their message alone (others are prefixed by their type: a likely bug).
EXPECTED_ERRORS = (ValueError, TypeError, OSError, ImportError)


def check_sb3_row(spec: RunSpec, env: Any, device: str) -> Any:
    """Check a row that SB3's ``learn`` trains: its class built on ``env`` without networks (returned); the
    constructor checks its arguments, EF's ``ef_kwargs`` among them."""
    return new_model(spec, env, device, _init_setup_model=False)


def check_curl_row(spec: RunSpec, env: Any, device: str) -> None:
    """Check a ``curl`` row: :func:`check_sb3_row`, and its crop against the frames (checked with the networks)."""
    from sb3_ef.curl.crop import check_crop_size

    model = check_sb3_row(spec, env, device)
    _, height, width = model.observation_space.shape
    check_crop_size(model.crop_size, height, width, type(model).__name__)


#: The row check (``"module:function"``) of each registry key that :func:`check_sb3_row` does not check in full; by
#: path, as Dreamer-v3's lives in its workbench package, above the grid.
GRID_CHECKS = {"curl": f"{__name__}:check_curl_row", "dreamerv3": "sb3_ef.dreamerv3.grid_run:check_dreamerv3_row"}


def _describe(error: Exception) -> str:
    """An error of a row's check as one line: its message (with its type when unexpected) and its notes."""
    message = " ".join(str(error).split()) or type(error).__name__
    if not isinstance(error, EXPECTED_ERRORS):
        message = f"{type(error).__name__}: {message}"
    return " ".join([message, *getattr(error, "__notes__", ())])


def check_row(spec: RunSpec, device: str = "auto") -> None:
    """Raise what the start of ``spec``'s run would raise (module docstring); nothing is trained or written."""
    env = build_training_env(spec, seed=spec.seed)
    try:
        algorithm_class(spec.algo, "RunSpec.algo")  # a known key
        (import_target(GRID_CHECKS[spec.algo]) if spec.algo in GRID_CHECKS else check_sb3_row)(spec, env, device)
    finally:
        env.close()


def check_rows(runs: Sequence[RunSpec], out: str | os.PathLike, device: str = "auto") -> list[str]:
    """The problems of the unfinished rows of ``runs``, one line each (``<label> on <task>: ...``)."""
    rows: dict[tuple[str, str], RunSpec] = {}
    for spec in runs:
        if read_result(RunPaths.of(out, spec)) is None:
            rows.setdefault((spec.label, spec.task), spec)
    problems = []
    for (label, task), spec in rows.items():
        try:
            check_row(spec, device)
        except Exception as error:  # each row's problem is reported; the others are still checked
            problems.append(f"{label} on {task}: {_describe(error)}")
    return problems
