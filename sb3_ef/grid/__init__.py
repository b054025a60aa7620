"""Benchmark grids: algorithms x tasks x seeds from the zoo configs, run on a local process pool or on Ray,
skipping finished runs and resuming interrupted ones, into one folder `sb3-ef analyze results` reads.

``sb3-ef benchmark GRID.yml --out DIR`` (:mod:`sb3_ef.grid.cli`); from Python::

    from sb3_ef.grid import grid_runs, run_benchmark
    runs = grid_runs(["drqv2", "drqv2_ef"], ["dmc/cartpole-balance-v0"], seeds=3, eval_freq=2000, n_timesteps=20000)
    run_benchmark(runs, "results", workers=2)

See docs/benchmark.md.
"""

from sb3_ef.grid.grid import Algorithm, RunSpec, grid_runs, load_grid
from sb3_ef.grid.run import RunResult, execute_run
from sb3_ef.grid.runner import run_benchmark

__all__ = ["Algorithm", "RunResult", "RunSpec", "execute_run", "grid_runs", "load_grid", "run_benchmark"]
