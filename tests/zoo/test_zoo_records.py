"""rl-zoo3 evaluations.npz -> evaluation CSVs for sb3_ef.analysis (known answers on hand-made run folders)."""

from __future__ import annotations

import csv
from collections import OrderedDict

import numpy as np
import pytest
import yaml

from sb3_ef.analysis.metrics import load_records
from sb3_ef.zoo.records import export_records, main


def make_run(log_folder, algo, env_id, run, seed, timesteps, results, successes=None):
    """A run folder laid out as rl-zoo3 writes it (args.yml dumped from an OrderedDict, like rl-zoo3)."""
    name = env_id.replace("/", "-")
    run_folder = log_folder / algo / f"{name}_{run}"
    (run_folder / name).mkdir(parents=True)
    extra = {} if successes is None else {"successes": successes}
    np.savez(run_folder / "evaluations.npz", timesteps=timesteps, results=results, ep_lengths=results, **extra)
    with open(run_folder / name / "args.yml", "w") as file:
        yaml.dump(OrderedDict([("env", env_id), ("seed", seed)]), file)


def read_rows(path):
    with open(path, newline="") as file:
        return list(csv.DictReader(file))


def test_dmc_run_gives_mean_returns_per_evaluation(tmp_path):
    make_run(tmp_path / "logs", "drqv2_ef", "dmc/cheetah-run-v0", 1, 7, [100, 200], [[1.0, 3.0], [5.0, 7.0]])
    [path] = export_records(str(tmp_path / "logs"), str(tmp_path / "out"))
    assert path == str(tmp_path / "out" / "DrQv2EF" / "dmc-cheetah-run-v0_1.csv")
    rows = read_rows(path)
    assert [(row["step"], row["frame"], row["return"], row["success"]) for row in rows] == [
        ("100", "200", "2.0", ""),
        ("200", "400", "6.0", ""),
    ]
    assert {(row["algo"], row["task"], row["seed"]) for row in rows} == {("DrQv2EF", "dmc/cheetah-run-v0", "7")}


def test_metaworld_run_keeps_success_rates_and_analysis_reads_the_files(tmp_path):
    logs = tmp_path / "logs"
    make_run(logs, "drqv2", "metaworld/hammer-v0", 2, 0, [50], [[10.0, 20.0]], successes=[[True, False]])
    make_run(logs, "drqv2_ef", "metaworld/hammer-v0", 1, 0, [50], [[30.0, 40.0]], successes=[[True, True]])
    export_records(str(logs), str(tmp_path / "out"), action_repeat=1)
    records = load_records(tmp_path / "out").sort_values("algo")
    assert records["success"].tolist() == [0.5, 1.0]
    assert records["frame"].tolist() == [50, 50]


def test_exporting_twice_replaces_the_files_and_empty_logs_are_refused(tmp_path, capsys):
    make_run(tmp_path / "logs", "tdmpc2", "dmc/walker-walk-v0", 1, 3, [10], [[1.0]])
    main([str(tmp_path / "logs"), str(tmp_path / "out")])
    main([str(tmp_path / "logs"), str(tmp_path / "out")])
    assert len(read_rows(tmp_path / "out" / "TDMPC2" / "dmc-walker-walk-v0_1.csv")) == 1
    assert "1 run(s)" in capsys.readouterr().out
    with pytest.raises(FileNotFoundError, match="--eval-freq"):
        export_records(str(tmp_path / "nothing"), str(tmp_path / "out"))


def test_zoo_runs_and_the_recorder_callback_name_an_algorithm_alike(tmp_path):
    """A results folder mixing an rl-zoo3 export and EvalRecorderCallback CSVs holds one algorithm, not two."""
    from stable_baselines3.common.callbacks import EvalCallback

    from sb3_ef import DrQv2EF
    from sb3_ef.analysis.records import EvalRecorderCallback
    from sb3_ef.envs.toy import ToyAgentEnv

    make_run(tmp_path / "logs", "drqv2_ef", "toy/agent-v0", 1, 0, [4], [[1.0]])
    export_records(str(tmp_path / "logs"), str(tmp_path / "out"))
    tiny = {"features_dim": 16, "agent_dim": 4, "net_arch": [8]}
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32, max_episode_steps=5), buffer_size=50, learning_starts=50,
                    babbling_steps=0, ef_horizon=3, policy_kwargs=tiny)  # fmt: skip
    recorder = EvalRecorderCallback(str(tmp_path / "out" / "python" / "toy_1.csv"), task="toy/agent-v0", seed=1)
    evaluation = EvalCallback(ToyAgentEnv(size=32, max_episode_steps=5), eval_freq=4, n_eval_episodes=1,
                              callback_after_eval=recorder)  # fmt: skip
    model.learn(4, callback=evaluation)
    assert set(load_records(tmp_path / "out")["algo"]) == {"DrQv2EF"}
