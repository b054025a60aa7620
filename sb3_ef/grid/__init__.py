"""Benchmark grids: algorithms x tasks x seeds from the zoo configs, run on a local process pool or on Ray,
skipping finished runs and resuming interrupted ones, into one folder `sb3-ef analyze results` reads.

``sb3-ef benchmark GRID.yml --out DIR`` (:mod:`sb3_ef.grid.cli`); from Python::

    from sb3_ef.grid import grid_runs, run_benchmark
    runs = grid_runs(["drqv2", "drqv2_ef"], ["dmc/cartpole-balance-v0"], seeds=3, eval_freq=2000, n_timesteps=20000)
    run_benchmark(runs, "results", workers=2)

See docs/benchmark.md. The public names are imported on first use, so that ``sb3-ef benchmark`` checks its
arguments before SB3 and torch are imported.
"""

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
