"""The tiny grid on a real Ray cluster started by the test on this machine, with a run that fails."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

from sb3_ef.grid import grid_runs, load_grid, run_benchmark
from sb3_ef.grid.run import RunPaths

ray = pytest.importorskip("ray")

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"


@pytest.fixture
def local_cluster():
    """A two-CPU Ray cluster on this machine (its own processes, shut down after the test)."""
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


def test_ray_runs_the_grid_retries_a_failing_run_and_gathers_the_records(local_cluster, tmp_path):
    good = load_grid(TINY_GRID)
    # A run that fails inside its task (the toy env refuses 4-pixel frames), after the grid was accepted.
    [bad] = grid_runs(
        {"broken": {"algo": "drqv2"}}, ["toy/agent-v0"], seeds=[0], eval_freq=100, n_timesteps=200,
        env_kwargs={"size": 4}, hyperparams=dict(good[0].hyperparams),
    )  # fmt: skip
    lines: list[str] = []
    results = run_benchmark([*good, bad], tmp_path, backend="ray", threads=1, retries=1, log=lines.append)

    assert [result.status for result in results] == ["done"] * 4 + ["failed"]
    assert "size must be >= 8" in results[-1].error
    for spec in good:
        with open(RunPaths.of(tmp_path, spec).records, newline="") as file:
            assert [row["step"] for row in csv.DictReader(file)] == ["100", "200"]
    *progress, summary = lines
    assert sum(" done " in line for line in progress) == 4 and sum(" failed " in line for line in progress) == 1
    assert summary.splitlines()[-1].split()[:4] == ["broken", "toy/agent-v0", "0/1", "1"]
