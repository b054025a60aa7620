"""A benchmark run resumed from a checkpoint records the evaluations of the uninterrupted run."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

from sb3_ef.analysis.records import read_records
from sb3_ef.grid import load_grid
from sb3_ef.grid.run import RunPaths, execute_run

TINY_GRID = Path(__file__).parent / "tiny_grid.yml"


def test_a_resumed_run_records_the_evaluations_of_the_uninterrupted_run(tmp_path):
    tiny = next(spec for spec in load_grid(TINY_GRID) if spec.run_id == "drqv2_ef/dmc-cartpole-balance-v0_s0")
    # 20-step episodes: the checkpoint at 80 falls on an episode boundary, after the updates have started (50)
    spec = replace(tiny, n_timesteps=200, eval_freq=40, checkpoint_freq=40, eval_episodes=2)
    execute_run(spec, tmp_path / "whole")
    execute_run(replace(spec, n_timesteps=120), tmp_path / "resumed", keep_checkpoints=None)
    resumed_paths = RunPaths.of(tmp_path / "resumed", spec)
    resumed_paths.result.unlink()  # the 120-step run is finished; a longer one resumes from its newest checkpoint
    resumed = execute_run(spec, tmp_path / "resumed")

    assert resumed.status == "done" and resumed.resumed_from == 80
    whole = [(row["step"], row["return"]) for row in read_records(RunPaths.of(tmp_path / "whole", spec).records)]
    assert [step for step, _ in whole] == [40, 80, 120, 160, 200]
    assert [(row["step"], row["return"]) for row in read_records(resumed_paths.records)] == whole
    assert len({value for _, value in whole}) > 1  # evaluations at different steps play different episodes
