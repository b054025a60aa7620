"""A ``dreamerv3`` row of ``sb3-ef benchmark``: expanded from its zoo config, trained to the end with the
evaluation CSV of every row, resumed from its checkpoint, read by ``sb3-ef analyze results``."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from sb3_ef.analysis.records import read_records
from sb3_ef.cli import main as sb3_ef_main
from sb3_ef.dreamerv3.callbacks import read_latest
from sb3_ef.grid import grid_runs, load_grid, run_benchmark
from sb3_ef.grid.run import RunPaths, execute_run

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"
REPO = Path(__file__).parents[2]


def test_the_row_takes_the_zoo_entry_and_the_grid_overrides():
    [spec] = load_grid(TINY_GRID)
    assert (spec.run_id, spec.algo, spec.action_repeat) == ("dreamerv3/toy-agent-v0_s0", "dreamerv3", 1)
    assert spec.env_kwargs == {"size": 16, "frame_stack": 1, "max_episode_steps": 25}
    assert spec.hyperparams["batch_size"] == 4 and spec.hyperparams["model_size"] == "XS"
    assert spec.hyperparams["sheeprl_overrides"]["algo.dense_units"] == 64


def test_a_mistyped_key_fails_when_the_grid_is_read():
    with pytest.raises(ValueError, match=r"unknown key 'replay_ration' for dreamerv3.*did you mean 'replay_ratio'"):
        grid_runs(["dreamerv3"], ["toy/agent-v0"], seeds=1, eval_freq=10, hyperparams={"replay_ration": 1.0})


@pytest.fixture(scope="module")
def stopped_and_resumed(tmp_path_factory):
    """The row trained to step 40 (its checkpoint kept), then, as a longer run, resumed there to step 60."""
    pytest.importorskip("sheeprl")
    out = tmp_path_factory.mktemp("bench")
    [spec] = load_grid(TINY_GRID)
    first = execute_run(replace(spec, n_timesteps=40), out, keep_checkpoints=None)
    paths = RunPaths.of(out, spec)
    before = read_records(paths.records)
    latest = read_latest(paths.checkpoints)
    paths.result.unlink()  # the 40-step run is finished; the 60-step one resumes from its newest checkpoint
    resumed = execute_run(spec, out)
    return spec, out, first, before, latest, resumed


def test_the_row_trains_to_the_end_and_resumes_from_its_checkpoint(stopped_and_resumed):
    spec, out, first, before, latest, resumed = stopped_and_resumed
    paths = RunPaths.of(out, spec)
    assert first.status == "done" and first.steps == 40 and latest is not None and latest["step"] == 40
    assert [row["step"] for row in before] == [20, 40]
    assert resumed.status == "done" and resumed.steps == 60 and resumed.resumed_from == 40
    rows = read_records(paths.records)
    assert [(row["algo"], row["task"], row["seed"], row["step"], row["frame"]) for row in rows] == [
        ("DreamerV3", "toy/agent-v0", "0", step, step) for step in (20, 40, 60)
    ]
    assert rows[:2] == before  # the rows up to the checkpoint are kept as they were
    assert resumed.final_return == rows[-1]["return"] and len(resumed.records) == 3
    assert paths.model.is_file() and paths.result.is_file() and not paths.checkpoints.exists()


def test_the_final_model_loads_and_the_rerun_skips_the_finished_row(stopped_and_resumed):
    from sb3_ef.dreamerv3 import DreamerV3

    spec, out, *_ = stopped_and_resumed
    paths = RunPaths.of(out, spec)
    assert DreamerV3.load(paths.model, device="cpu", work_dir=out / "loaded").num_timesteps == 60
    assert execute_run(spec, out).status == "skipped"


def test_analyze_results_reads_the_row(stopped_and_resumed, tmp_path):
    _, out, *_ = stopped_and_resumed
    assert sb3_ef_main(["analyze", "results", str(out), "--out", str(tmp_path), "--reps", "20"]) == 0
    with open(tmp_path / "scores.csv", newline="") as file:
        assert {(row["algo"], row["task"]) for row in csv.DictReader(file)} == {("DreamerV3", "toy/agent-v0")}


@pytest.mark.parametrize(
    ("task", "success"),
    [("dmc/cartpole-balance-v0", ""), ("metaworld/reach-v0", {"0.0", "1.0"})],
)
def test_rows_run_on_make_env_pixels_at_action_repeat_2(task, success, tmp_path):
    """DMC and Meta-World frames from make_env (32x32 without shadows, 20-step episodes at action repeat 2)."""
    pytest.importorskip("sheeprl")
    [toy] = load_grid(TINY_GRID)
    [spec] = grid_runs(
        {"dreamerv3": {"hyperparams": dict(toy.hyperparams)}}, [task], seeds=[1], eval_freq=20, eval_episodes=1,
        n_timesteps=40, env_kwargs={"size": 32, "fast_render": True, "episode_length": 40},
    )  # fmt: skip
    result = execute_run(spec, tmp_path)
    assert result.status == "done" and result.steps == 40
    rows = read_records(RunPaths.of(tmp_path, spec).records)
    assert [(row["algo"], row["task"], row["seed"], row["step"], row["frame"]) for row in rows] == [
        ("DreamerV3", task, "1", step, 2 * step) for step in (20, 40)
    ]
    assert all(row["success"] in success if success else row["success"] == "" for row in rows)


@pytest.mark.slow
def test_a_row_killed_midway_is_completed_from_its_checkpoint_by_the_rerun(tmp_path):
    """Kill `sb3-ef benchmark` (driver and worker) after the row's first checkpoint; the rerun resumes there and
    records every evaluation once."""
    pytest.importorskip("sheeprl")
    document = yaml.safe_load(TINY_GRID.read_text())
    document["grids"][0].update(n_timesteps=400)
    grid = tmp_path / "grid.yml"
    grid.write_text(yaml.safe_dump(document))
    [spec] = load_grid(grid)
    paths = RunPaths.of(tmp_path / "out", spec)
    command = [sys.executable, "-m", "sb3_ef.cli", "benchmark", str(grid), "--out", str(tmp_path / "out")]
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    process = subprocess.Popen(command, env=environment, start_new_session=True, stdout=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 300
        while read_latest_or_none(paths.checkpoints) is None and time.monotonic() < deadline:
            assert process.poll() is None, "the run ended before its first checkpoint"
            time.sleep(0.2)
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the driver and its worker: this test started the session
        process.wait()
    assert not paths.result.exists()

    [result] = run_benchmark([spec], tmp_path / "out", log=lambda line: None)
    assert result.status == "done" and result.steps == 400
    assert result.resumed_from is not None and 40 <= result.resumed_from < 400
    assert [row["step"] for row in read_records(paths.records)] == list(range(20, 401, 20))  # once each


def read_latest_or_none(folder: Path) -> dict | None:
    """The latest checkpoint of a run being written by another process (``None`` before its first one)."""
    try:
        return read_latest(folder)
    except FileNotFoundError:  # named, and removed since by sheeprl's keep_last: a newer one is named now
        return None
