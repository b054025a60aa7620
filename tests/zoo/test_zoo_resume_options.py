"""``sb3-ef train --resume`` keeps every recorded option the new command line does not set, checkpoints keep the
replay buffer of the run they continue, and the run folder holds the evaluation records `analyze results` reads."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import yaml

from sb3_ef.analysis.metrics import load_records
from sb3_ef.common.checkpoints import latest_checkpoint, list_checkpoints
from sb3_ef.zoo import train
from sb3_ef.zoo.options import SB3_EF_TRAIN_OPTIONS, TRAIN_OPTIONS, build_parser, merge_train_argv
from tests.helpers.zoo import cli_pairs

ENV_ID, ENV_NAME = "toy/agent-v0", "toy-agent-v0"
HYPERPARAMS = {
    "buffer_size": 300,
    "batch_size": 8,
    "learning_starts": 20,
    "ef_horizon": 3,
    "babbling_steps": 0,
    "policy_kwargs": {
        "net_arch": [16],
        "trunk_dim": 8,
        "features_dim": 16,
        "agent_dim": 4,
        "ef_kwargs": {"decoder_channels": 4, "rollout_hidden_dims": (8,)},
    },
}


def _argv(log_folder, n_timesteps: int, *extra: str) -> list[str]:
    return [
        "--algo", "drqv2_ef", "--env", ENV_ID, "-n", str(n_timesteps), "-f", str(log_folder), "--seed", "0",
        "--eval-freq", "20", "--eval-episodes", "1", "--save-freq", "20", "--num-threads", "1", "--verbose", "0",
        "--env-kwargs", "size:32", "max_episode_steps:20", "--hyperparams", *cli_pairs(HYPERPARAMS), *extra,
    ]  # fmt: skip


def _record_steps(run) -> list[int]:
    with open(run / f"{ENV_NAME}.csv", newline="") as file:
        return [int(row["step"]) for row in csv.DictReader(file)]


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """A run to 60 steps with --checkpoint-buffer --keep-checkpoints 1, killed (no final model), then resumed to 100
    steps with one --hyperparams key changed."""
    logs = tmp_path_factory.mktemp("logs")
    train.main(_argv(logs, 60, "--checkpoint-buffer", "--keep-checkpoints", "1"))
    run = logs / "drqv2_ef" / f"{ENV_NAME}_1"
    (run / f"{ENV_NAME}.zip").unlink()  # a killed run has no final model and is not marked finished
    (run / ENV_NAME / "result.json").unlink()
    first = {"records": _record_steps(run), "checkpoint": latest_checkpoint(run)}
    train.main(["--resume", str(run), "-n", "100", "--hyperparams", "batch_size:4"])
    return run, first


def test_resume_keeps_the_recorded_options_and_merges_the_new_ones(resumed):
    run, first = resumed
    assert first["checkpoint"].step == 40 and first["checkpoint"].replay_buffer_path is not None
    # The resumed run trained with the recorded hyperparameters, batch_size changed.
    with open(run / ENV_NAME / "config.yml") as file:
        config = dict(yaml.load(file, Loader=yaml.UnsafeLoader))  # rl-zoo3 writes pairs with Python tags
    assert (config["batch_size"], config["buffer_size"], config["ef_horizon"]) == (4, 300, 3)
    # Its checkpoints carry the replay buffer, and --keep-checkpoints 1 is still in force.
    [checkpoint] = list_checkpoints(run)
    assert checkpoint.step == 80 and checkpoint.replay_buffer_path is not None
    # The merged command line is recorded for the next --resume.
    recorded = json.loads((run / ENV_NAME / "train_argv.json").read_text())
    args = build_parser((*TRAIN_OPTIONS, *SB3_EF_TRAIN_OPTIONS), "test").parse_args(recorded)
    assert (args.checkpoint_buffer, args.keep_checkpoints, args.n_timesteps, args.save_freq) == (True, 1, 100, 20)
    assert {"batch_size:4", "buffer_size:300", "learning_starts:20"} <= set(args.hyperparams)


def test_the_run_folder_records_each_evaluation_once_and_is_marked_finished(resumed):
    run, first = resumed
    assert first["records"] == [20, 40, 60]
    # Resumed at the checkpoint of step 40: the evaluation at 60 was dropped and redone, the CSV holds each step once
    # (evaluations.npz, rl-zoo3's, holds 60 twice).
    assert _record_steps(run) == [20, 40, 60, 80, 100]
    assert np.load(run / "evaluations.npz")["timesteps"].tolist() == [20, 40, 60, 60, 80, 100]
    result = json.loads((run / ENV_NAME / "result.json").read_text())
    assert result["status"] == "finished" and result["steps"] == 100
    records = load_records(run.parent.parent, finished_only=True)  # what `sb3-ef analyze results logs` reads
    assert records["step"].astype(int).tolist() == [20, 40, 60, 80, 100]
    assert set(records["algo"]) == {"DrQv2EF"} and set(records["task"]) == {ENV_ID}


def test_continuing_a_checkpoint_that_holds_a_buffer_keeps_saving_it(resumed, capsys):
    """-i on a buffer-bearing checkpoint without --checkpoint-buffer: the new checkpoints hold the buffer too, so
    pruning (--keep-checkpoints 1) never leaves the run with buffer-less checkpoints only."""
    run, _ = resumed
    checkpoint = latest_checkpoint(run)
    given = [arg for arg in _argv(run.parent.parent, 140) if arg != "--checkpoint-buffer"]
    train.main([*given, "--keep-checkpoints", "1", "-i", str(checkpoint.model_path)])
    [newest] = list_checkpoints(run)
    assert newest.step > checkpoint.step and newest.replay_buffer_path is not None
    assert "has a replay buffer beside it: the run's checkpoints include it" in capsys.readouterr().out


def test_merge_train_argv_keeps_what_is_not_given():
    recorded = ["--algo", "sear", "-n", "60", "--checkpoint-buffer", "--keep-checkpoints", "3", "--seed", "-1",
                "--hyperparams", "a:1", "b:'x'", "--env-kwargs", "size:64", "-i", "old.zip"]  # fmt: skip
    merged = merge_train_argv(recorded, ["-n", "100", "--hyperparams", "b:2", "c:3", "-i", "new.zip"])
    args = build_parser((*TRAIN_OPTIONS, *SB3_EF_TRAIN_OPTIONS), "test").parse_args(merged)
    assert (args.algo, args.n_timesteps, args.seed, args.trained_agent) == ("sear", 100, -1, "new.zip")
    assert (args.checkpoint_buffer, args.keep_checkpoints) == (True, 3)
    assert args.hyperparams == ["a:1", "b:2", "c:3"] and args.env_kwargs == ["size:64"]
    assert merged.count("-i") == 1 and "--trained-agent" not in merged  # rl-zoo3's own spelling, once
