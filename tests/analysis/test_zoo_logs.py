"""`sb3-ef analyze results logs` on rl-zoo3 log folders: evaluations.npz read directly, runs named from their
folders and records."""

from __future__ import annotations

from collections import OrderedDict

import numpy as np
import pandas as pd
import pytest
import yaml

from sb3_ef.analysis.cli import main
from sb3_ef.analysis.metrics import load_records
from sb3_ef.analysis.records import append_records, record_row
from sb3_ef.analysis.zoo_logs import action_repeat_of, env_id_of_folder, zoo_run_records


def zoo_run(logs, algo, env_id, run, timesteps, results, args=None, config=None, successes=None, finished=True):
    """A run folder as rl-zoo3 writes it: EvalCallback's evaluations.npz (``np.savez`` of the same arrays),
    ``<env>/args.yml`` and ``<env>/config.yml`` dumped from OrderedDicts, and the final ``<env>.zip``."""
    name = env_id.replace("/", "-")
    folder = logs / algo / f"{name}_{run}"
    (folder / name).mkdir(parents=True)
    arrays = {"timesteps": np.asarray(timesteps), "results": np.asarray(results, dtype=float)}
    arrays["ep_lengths"] = np.full_like(arrays["results"], 500, dtype=int)
    if successes is not None:
        arrays["successes"] = np.asarray(successes)
    np.savez(folder / "evaluations.npz", **arrays)
    if args is not None:
        with open(folder / name / "args.yml", "w") as file:
            yaml.dump(OrderedDict([("env", env_id), *args.items()]), file)
    if config is not None:
        with open(folder / name / "config.yml", "w") as file:
            yaml.dump(OrderedDict(config), file)
    if finished:
        (folder / f"{name}.zip").write_bytes(b"PK\x05\x06" + bytes(18))  # an empty zip archive
    return folder


def test_a_zoo_run_becomes_records_like_the_recorders(tmp_path):
    zoo_run(tmp_path, "drqv2_ef", "dmc/cheetah-run-v0", 1, [100, 200], [[1.0, 3.0], [5.0, 7.0]], args={"seed": 7})
    records = load_records(tmp_path)
    assert records[["algo", "task", "seed"]].drop_duplicates().values.tolist() == [["DrQv2EF", "dmc/cheetah-run-v0", 7]]
    assert records["step"].tolist() == [100, 200] and records["frame"].tolist() == [200, 400]  # action repeat 2
    assert records["return"].tolist() == [2.0, 6.0] and records["success"].isna().all()


def test_action_repeat_and_successes_come_from_the_run(tmp_path):
    zoo_run(tmp_path, "drqv2", "metaworld/hammer-v3", 2, [50], [[10.0, 20.0]], successes=[[True, False]],
            args={"seed": 0, "env_kwargs": {"action_repeat": 4}})  # fmt: skip
    zoo_run(tmp_path, "drqv2", "toy/agent-v0", 1, [50], [[1.0]], args={"seed": 3},
            config={"env_kwargs": "dict(size=32)"})  # fmt: skip
    records = load_records(tmp_path).sort_values("task")
    assert records["frame"].tolist() == [200, 50]  # recorded action repeat 4; the toy env has none
    assert records["success"].iloc[0] == 0.5
    assert action_repeat_of("dmc/walker-walk-v0", {}) == 2 and action_repeat_of("CartPole-v1", {}) == 1


def test_without_args_yml_the_folder_names_the_run(tmp_path):
    zoo_run(tmp_path, "tdmpc2", "dmc/walker-walk-v0", 3, [10, 20], [[1.0], [2.0]])
    zoo_run(tmp_path, "tdmpc2", "dmc-distracting/walker-walk-v0", 1, [10], [[4.0]])
    records = load_records(tmp_path).sort_values(["task", "step"])
    assert records[["algo", "task", "seed"]].drop_duplicates().values.tolist() == [
        ["TDMPC2", "dmc-distracting/walker-walk-v0", 1],
        ["TDMPC2", "dmc/walker-walk-v0", 3],  # the run number stands in for the seed
    ]
    assert env_id_of_folder("dmc-cartpole-swingup-v0") == "dmc/cartpole-swingup-v0"
    assert env_id_of_folder("no-such-env-v0") == "no-such-env-v0"


def test_a_run_with_its_own_records_is_read_once(tmp_path):
    folder = zoo_run(tmp_path, "drqv2", "dmc/walker-walk-v0", 1, [100], [[1.0]], args={"seed": 0})
    append_records(folder / "records.csv", [record_row("DrQv2", "dmc/walker-walk-v0", 0, 100, 2, 9.0, None)])
    records = load_records(tmp_path)
    assert records["return"].tolist() == [9.0]  # the CSV, not evaluations.npz as well


def test_finished_only_keeps_runs_that_saved_their_final_model(tmp_path):
    zoo_run(tmp_path, "drqv2", "dmc/walker-walk-v0", 1, [100], [[1.0]], args={"seed": 0})
    zoo_run(tmp_path, "drqv2", "dmc/walker-walk-v0", 2, [100], [[2.0]], args={"seed": 1}, finished=False)
    assert sorted(load_records(tmp_path)["seed"]) == [0, 1]
    assert load_records(tmp_path, finished_only=True)["seed"].tolist() == [0]


def test_a_damaged_evaluations_file_is_named(tmp_path):
    folder = zoo_run(tmp_path, "drqv2", "dmc/walker-walk-v0", 1, [100], [[1.0]])
    np.savez(folder / "evaluations.npz", timesteps=np.array([100]))
    with pytest.raises(ValueError, match=r"evaluations.npz: expected rl-zoo3's EvalCallback arrays .* \['results'\]"):
        zoo_run_records(folder)
    (folder / "evaluations.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match=r"evaluations.npz is not a readable evaluations.npz"):
        main(["results", str(tmp_path)])
    assert not (tmp_path / "analysis").exists()


@pytest.mark.slow
def test_analyze_results_reads_the_logs_of_sb3_ef_train(tmp_path, capsys):
    """A real `sb3-ef train` run (rl-zoo3 writes the folder), then `sb3-ef analyze results logs` (about 30 s)."""
    from sb3_ef import cli
    from tests.helpers.zoo import train_args

    logs = tmp_path / "logs"
    args = train_args("drqv2", "dmc/cartpole-swingup-v0", str(logs), 120)
    assert cli.main(["train", *args, "--eval-freq", "60", "--eval-episodes", "1", "--seed", "5"]) == 0
    assert cli.main(["analyze", "results", str(logs), "--reps", "10", "--reference", "drqv2"]) == 0
    scores = pd.read_csv(logs / "analysis" / "scores.csv")
    runs = scores[["algo", "task", "seed"]].drop_duplicates().values.tolist()
    assert runs == [["DrQv2", "dmc/cartpole-swingup-v0", 5]]
    assert scores["step"].tolist() == [60, 120]
    assert pd.read_csv(logs / "analysis" / "reference_drqv2.csv")["x"].tolist() == [240]  # 120 steps x repeat 2
    assert "Scores of 1 algorithm(s) on 1 task(s)" in capsys.readouterr().out


def test_evaluations_outside_an_rl_zoo3_layout_are_not_read(tmp_path):
    zoo_run(tmp_path, "drqv2", "dmc/walker-walk-v0", 1, [100], [[1.0]], args={"seed": 0})
    elsewhere = tmp_path / "mine" / "evaluation_logs"  # an EvalCallback(log_path=...) of a user's own script
    elsewhere.mkdir(parents=True)
    np.savez(elsewhere / "evaluations.npz", timesteps=[5], results=[[9.0]], ep_lengths=[[5]])
    benchmark = tmp_path / "grid" / "drqv2" / "dmc-walker-walk-v0_7"  # a benchmark run: <run>.csv beside <run>/
    benchmark.mkdir(parents=True)
    np.savez(benchmark / "evaluations.npz", timesteps=[5], results=[[9.0]], ep_lengths=[[5]])
    append_records(benchmark.with_suffix(".csv"), [record_row("DrQv2", "dmc/walker-walk-v0", 7, 100, 2, 3.0, None)])
    records = load_records(tmp_path).sort_values("seed")
    assert records["seed"].tolist() == [0, 7] and records["return"].tolist() == [1.0, 3.0]
