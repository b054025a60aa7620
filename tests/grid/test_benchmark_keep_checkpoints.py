"""`--keep-checkpoints`: how many checkpoints a run keeps while it trains, or all of them for good."""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import pytest

from sb3_ef.common.checkpoints import list_checkpoints
from sb3_ef.grid import load_grid, run_benchmark
from sb3_ef.grid.cli import keep_count
from sb3_ef.grid.run import RunPaths, execute_run

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"


def test_keep_all_leaves_every_checkpoint_after_the_run(tmp_path):
    tiny = next(spec for spec in load_grid(TINY_GRID) if spec.run_id == "drqv2/dmc-cartpole-balance-v0_s0")
    spec = replace(tiny, n_timesteps=400)
    kept = execute_run(spec, tmp_path / "all", keep_checkpoints=None)
    assert kept.status == "done" and kept.steps == 400
    # a checkpoint is written at the rollout after its step, so 400 ends the run first; the default keeps 2
    checkpoints = list_checkpoints(RunPaths.of(tmp_path / "all", spec).checkpoints)
    assert [checkpoint.step for checkpoint in checkpoints] == [100, 200, 300]
    default = execute_run(tiny, tmp_path / "default")
    assert default.status == "done" and not RunPaths.of(tmp_path / "default", tiny).checkpoints.exists()


def test_keep_count_parses_a_count_or_all():
    assert keep_count("all") is None and keep_count("3") == 3
    for bad in ("0", "-1", "some"):
        with pytest.raises(argparse.ArgumentTypeError, match="a count >= 1 or 'all'"):
            keep_count(bad)


def test_a_bad_count_fails_before_any_run(tmp_path):
    with pytest.raises(ValueError, match="keep_checkpoints must be >= 1 or None"):
        run_benchmark(load_grid(TINY_GRID), tmp_path, keep_checkpoints=0)
    assert not any(tmp_path.iterdir())
