"""The study's grid file states the reduced settings its NOTES.md reports."""

from __future__ import annotations

from pathlib import Path

from sb3_ef.grid.grid import load_grid


def test_cpu_grid_states_the_reduced_settings_of_the_learning_evidence():
    every = load_grid(Path(__file__).resolve().parents[1] / "cpu_grid.yml")
    stall = [run for run in every if run.label.endswith("_stall")]
    runs = [run for run in every if not run.label.endswith("_stall")]
    assert {run.label for run in runs} == {"drqv2", "drqv2_ef", "drqv2_ef_beta1e-3", "drqv2_std100k"}
    assert {run.task for run in runs} == {"dmc/cartpole-balance-v0", "dmc/cartpole-swingup-v0"}
    assert {run.seed for run in runs} == {0, 1, 2} and len(runs) == 21
    for run in runs:
        assert (run.n_timesteps, run.eval_freq, run.eval_episodes, run.checkpoint_freq) == (20000, 2000, 5, 2000)
    for run in every:
        assert run.env_kwargs["size"] == 64 and run.hyperparams["batch_size"] == 64
        decay = "linear(1.0,0.1,100000)" if run.label == "drqv2_std100k" else "linear(1.0,0.1,10000)"
        assert run.hyperparams["exploration_std"] == decay
    assert {run.task for run in runs if run.label == "drqv2_std100k"} == {"dmc/cartpole-swingup-v0"}
    ef = {run.label: run.hyperparams for run in every if run.algo == "drqv2_ef"}
    assert ef["drqv2_ef"]["beta"] == 1.0 and ef["drqv2_ef_beta1e-3"]["beta"] == 1e-3
    assert ef["drqv2_ef"]["babbling_steps"] == 1000 and ef["drqv2_ef_stall"] == ef["drqv2_ef"]
    # The stall block: the main grid's settings on fresh seeds, evaluated twice as often, to 10k steps.
    assert {(run.label, run.algo) for run in stall} == {("drqv2_stall", "drqv2"), ("drqv2_ef_stall", "drqv2_ef")}
    assert {run.seed for run in stall} == {3, 4, 5} and {run.task for run in stall} == {"dmc/cartpole-balance-v0"}
    assert {(run.n_timesteps, run.eval_freq, run.checkpoint_freq) for run in stall} == {(10000, 1000, 2000)}
    drqv2 = {run.label: run.hyperparams for run in every if run.algo == "drqv2"}
    assert drqv2["drqv2_stall"] == drqv2["drqv2"]
