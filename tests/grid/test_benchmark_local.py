"""The tiny grid on the local process pool: records, progress, a rerun that skips everything, a run killed midway
and completed by the rerun, and `sb3-ef analyze results` on the output."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.cli import main as sb3_ef_main
from sb3_ef.grid import grid_runs, load_grid, run_benchmark
from sb3_ef.grid.run import RunPaths

# Four spawned training processes take 30-90 s on 2 loaded cores: the default run covers the runner on Ray
# (test_benchmark_ray.py) and the grid expansion; these run with -m slow.
pytestmark = pytest.mark.slow

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"
REPO = Path(__file__).parents[2]


def read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> tuple[Path, list[str]]:
    """The tiny grid (2 algorithms x cartpole-balance x 2 seeds, 200 steps) trained with two runs in parallel."""
    out = tmp_path_factory.mktemp("bench")
    lines: list[str] = []
    run_benchmark(load_grid(TINY_GRID), out, workers=2, threads=1, log=lines.append)
    return out, lines


def test_every_run_writes_its_evaluation_records_and_result(trained):
    out, _ = trained
    for spec in load_grid(TINY_GRID):
        paths = RunPaths.of(out, spec)
        assert paths.records == out / spec.label / f"dmc-cartpole-balance-v0_s{spec.seed}.csv"
        rows = read_csv(paths.records)
        assert tuple(rows[0]) == RECORD_COLUMNS
        name = {"drqv2": "DrQv2", "drqv2_ef": "DrQv2EF"}[spec.label]  # the class name, as every record writer
        assert [(row["algo"], row["task"], row["seed"], row["step"]) for row in rows] == [
            (name, "dmc/cartpole-balance-v0", str(spec.seed), "100"),
            (name, "dmc/cartpole-balance-v0", str(spec.seed), "200"),
        ]
        result = json.loads(paths.result.read_text())
        assert result["status"] == "done" and result["steps"] == 200 and result["resumed_from"] is None
        assert result["final_return"] == float(rows[-1]["return"])
        assert paths.model.is_file() and not paths.checkpoints.exists()  # checkpoints go once the run is finished


def test_progress_has_a_start_and_a_finish_line_per_run_and_a_summary(trained):
    _, lines = trained
    starts = [line for line in lines if " start " in line]
    finishes = [line for line in lines if " done " in line]
    assert len(starts) == len(finishes) == 4
    assert all(" s  return " in line and "at step 200" in line for line in finishes)
    summary = lines[-1].splitlines()
    assert summary[0].split() == ["algorithm", "task", "finished", "failed", "final", "return", "hours"]
    assert [row.split()[:4] for row in summary[2:]] == [
        ["drqv2", "dmc/cartpole-balance-v0", "2/2", "0"],
        ["drqv2_ef", "dmc/cartpole-balance-v0", "2/2", "0"],
    ]


def test_a_rerun_skips_every_finished_run(trained, capsys):
    out, _ = trained
    before = {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()}
    assert sb3_ef_main(["benchmark", str(TINY_GRID), "--out", str(out), "--workers", "2"]) == 0
    printed = capsys.readouterr().out
    assert printed.count(" skipped ") == 4 and " start " not in printed
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == before
    assert sb3_ef_main(["benchmark", str(TINY_GRID), "--out", str(out), "--dry-run"]) == 0
    assert capsys.readouterr().out.count("2 finished") == 2


def test_analyze_results_reads_the_benchmark_folder(trained, tmp_path, capsys):
    out, _ = trained
    assert sb3_ef_main(["analyze", "results", str(out), "--out", str(tmp_path), "--reps", "50"]) == 0
    scores = read_csv(tmp_path / "scores.csv")
    # Records name the algorithms by class, as EvalRecorderCallback and the zoo export do.
    assert {(row["algo"], row["seed"]) for row in scores} == {(a, s) for a in ("DrQv2", "DrQv2EF") for s in "01"}
    assert (tmp_path / "ens.csv").is_file() and (tmp_path / "rliable.csv").is_file()


def test_a_failing_run_is_retried_then_reported_and_the_others_finish(tmp_path):
    [good, *_] = load_grid(TINY_GRID)
    [bad] = grid_runs(
        {"broken": {"algo": "drqv2"}}, ["toy/agent-v0"], seeds=[0], eval_freq=100, n_timesteps=200,
        env_kwargs={"size": 4}, hyperparams=dict(good.hyperparams),
    )  # fmt: skip
    lines: list[str] = []
    results = run_benchmark([good, bad], tmp_path, workers=2, retries=1, log=lines.append)
    assert [result.status for result in results] == ["done", "failed"]
    assert results[1].error == "ValueError: size must be >= 8 pixels, got 4"
    assert sum(" retry " in line and "broken/" in line for line in lines) == 1
    assert not RunPaths.of(tmp_path, bad).result.exists()  # a failed run is tried again by the next invocation


def test_a_run_killed_midway_is_completed_from_its_checkpoint_by_the_rerun(tmp_path):
    """Kill the benchmark (driver and worker) after the first checkpoint; the rerun resumes there."""
    document = yaml.safe_load(TINY_GRID.read_text())
    block = document["grids"][0]
    block.update(algorithms={"drqv2": block["algorithms"]["drqv2"]}, seeds=[0], n_timesteps=1000)
    grid = tmp_path / "grid.yml"
    grid.write_text(yaml.safe_dump(document))
    [spec] = load_grid(grid)
    paths = RunPaths.of(tmp_path / "out", spec)
    command = [sys.executable, "-m", "sb3_ef.cli", "benchmark", str(grid), "--out", str(tmp_path / "out")]
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.Popen(command, env=environment, start_new_session=True, stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not list(paths.checkpoints.glob("rl_model_*_steps.zip")) and time.monotonic() < deadline:
            assert process.poll() is None, "the run ended before its first checkpoint"
            time.sleep(0.1)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the driver and its worker: this test started the session
        process.wait()
    assert not paths.result.exists()

    [result] = run_benchmark([spec], tmp_path / "out", log=lambda line: None)
    assert result.status == "done" and result.steps == 1000
    assert result.resumed_from is not None and 100 <= result.resumed_from < 1000
    steps = [int(row["step"]) for row in read_csv(paths.records)]
    assert steps == list(range(100, 1001, 100))  # every evaluation once: none lost, none repeated
