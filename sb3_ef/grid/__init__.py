"""Benchmark grids run on a local process pool or on Ray, resuming interrupted runs (docs/benchmark.md).
Public names are imported on first use, so that ``sb3-ef benchmark`` checks its arguments before torch."""

from __future__ import annotations

from sb3_ef.common.lazy import lazy_attributes

_PUBLIC = {
    "Algorithm": "sb3_ef.grid.grid",
    "RunSpec": "sb3_ef.grid.grid",
    "grid_runs": "sb3_ef.grid.grid",
    "load_grid": "sb3_ef.grid.grid",
    "RunResult": "sb3_ef.grid.run",
    "execute_run": "sb3_ef.grid.run",
    "run_benchmark": "sb3_ef.grid.runner",
}

__all__ = list(_PUBLIC)

__getattr__ = lazy_attributes(__name__, _PUBLIC)
