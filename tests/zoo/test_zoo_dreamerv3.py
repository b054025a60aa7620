"""``sb3-ef train|enjoy --algo dreamerv3``: the registry's own-loop functions, with an rl-zoo3 run folder's files,
``--resume`` and ``analyze results``; rl-zoo3's options that do not apply are refused at once."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sb3_ef.analysis.records import read_records
from sb3_ef.cli import main as sb3_ef_main
from sb3_ef.zoo.train import own_loop_main

#: The toy/agent-v0 entry of zoo_configs/dreamerv3.yml with a shorter warm-up and smaller batches.
TINY = ["--hyperparams", "buffer_size:2000", "learning_starts:16", "batch_size:4", "sequence_length:8"]
REPO = Path(__file__).parents[2]
TRAIN = ["train", "--algo", "dreamerv3", "--env", "toy/agent-v0", "--eval-freq", "20", "--eval-episodes", "1"]


def test_the_registry_routes_dreamerv3_to_its_own_loop_and_the_others_to_rl_zoo3(tmp_path):
    assert own_loop_main(["--algo", "dreamerv3"], "train").__name__ == "train_main"
    assert own_loop_main(["--algo", "dreamerv3"], "enjoy").__name__ == "enjoy_main"
    assert own_loop_main(["--algo", "drqv2_ef"], "train") is None
    run = tmp_path / "dreamerv3" / "toy-agent-v0_1"
    (run / "toy-agent-v0").mkdir(parents=True)
    (run / "toy-agent-v0" / "train_argv.json").write_text(json.dumps(["--algo", "dreamerv3", "--env", "toy/agent-v0"]))
    assert own_loop_main(["--resume", str(run)], "train").__name__ == "train_main"  # the run's recorded algorithm


@pytest.mark.parametrize(
    "extra, option",
    [(["-optimize"], "-optimize"), (["--vec-env", "subproc"], "--vec-env"), (["-tb", "tb"], "-tb")],
)
def test_rl_zoo3_options_that_do_not_apply_are_refused_with_the_ones_that_do(tmp_path, capsys, extra, option):
    assert sb3_ef_main([*TRAIN, "-f", str(tmp_path), *extra]) == 2
    error = capsys.readouterr().err
    assert f"{option} is not supported for --algo dreamerv3" in error and "--save-freq" in error
    assert not (tmp_path / "dreamerv3").exists()


def test_train_enjoy_resume_and_analyze(tmp_path, capsys):
    pytest.importorskip("sheeprl")
    logs = tmp_path / "logs"
    assert sb3_ef_main([*TRAIN, "-n", "40", "--save-freq", "20", "-f", str(logs), "--seed", "0", *TINY]) == 0
    run = logs / "dreamerv3" / "toy-agent-v0_1"
    params = run / "toy-agent-v0"
    assert {"args.yml", "config.yml", "train_argv.json", "result.json", "checkpoints"} <= {
        p.name for p in params.iterdir()
    }
    assert (run / "toy-agent-v0.zip").is_file()
    assert [row["step"] for row in read_records(run / "toy-agent-v0.csv")] == [20, 40]
    assert json.loads((params / "result.json").read_text())["steps"] == 40

    capsys.readouterr()
    assert sb3_ef_main(["enjoy", "--algo", "dreamerv3", "--env", "toy/agent-v0", "-f", str(logs), "-n", "30"]) == 0
    assert "Episode Reward:" in capsys.readouterr().out  # the toy env's episodes are 25 steps

    assert sb3_ef_main(["train", "--resume", str(run), "-n", "60"]) == 0
    rows = read_records(run / "toy-agent-v0.csv")
    assert [row["step"] for row in rows] == [20, 40, 60] and {row["algo"] for row in rows} == {"DreamerV3"}
    assert json.loads((params / "result.json").read_text())["steps"] == 60
    assert not (logs / "dreamerv3" / "toy-agent-v0_2").exists()  # continued in its own folder

    assert sb3_ef_main(["analyze", "results", str(logs), "--finished-only", "--out", str(tmp_path / "a")]) == 0
    assert "DreamerV3" in capsys.readouterr().out


def test_the_default_evaluation_interval_trains_any_number_of_steps(tmp_path, capsys):
    """-n 30 with rl-zoo3's default --eval-freq (25000) and no --save-freq: no evaluation, one checkpoint at the end."""
    pytest.importorskip("sheeprl")
    train = ["train", "--algo", "dreamerv3", "--env", "toy/agent-v0", "-n", "30", "-f", str(tmp_path), *TINY]
    assert sb3_ef_main([*train, "--seed", "0"]) == 0, capsys.readouterr().err
    params = tmp_path / "dreamerv3" / "toy-agent-v0_1" / "toy-agent-v0"
    assert json.loads((params / "result.json").read_text())["steps"] == 30
    assert (params.parent / "toy-agent-v0.zip").is_file()


def test_no_evaluation_is_refused_before_anything_is_written(tmp_path, capsys):
    assert sb3_ef_main([*TRAIN[:5], "--eval-freq", "-1", "-f", str(tmp_path)]) == 2
    assert "--eval-freq -1 (no evaluation) does not apply to --algo dreamerv3" in capsys.readouterr().err
    assert not (tmp_path / "dreamerv3").exists()


def test_enjoy_names_the_run_and_the_file_it_lacks(tmp_path, capsys):
    enjoy = ["enjoy", "--algo", "dreamerv3", "--env", "toy/agent-v0", "-f", str(tmp_path)]
    run = tmp_path / "dreamerv3" / "toy-agent-v0_1"
    (run / "toy-agent-v0").mkdir(parents=True)
    assert sb3_ef_main(enjoy) == 2
    assert f"Cannot enjoy the run {run}: {run}/toy-agent-v0.zip is missing (`sb3-ef train` writes it when" in (
        capsys.readouterr().err
    )
    (run / "toy-agent-v0.zip").touch()
    assert sb3_ef_main(enjoy) == 2
    assert f"Cannot enjoy the run {run}: {run}/toy-agent-v0/args.yml is missing" in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_saves_the_model_and_exits_130(tmp_path):
    """SIGINT after the first checkpoint: the newest weights saved as the run's model, exit status 130, the line
    naming the step, the file, the last checkpoint and the command that continues the run."""
    pytest.importorskip("sheeprl")
    train = [*TRAIN[:5], "-n", "10000", "--eval-freq", "5", "--eval-episodes", "1", "--save-freq", "5"]
    command = [sys.executable, "-m", "sb3_ef.cli", *train, "-f", str(tmp_path), "--seed", "0", *TINY]
    environment = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    run = tmp_path / "dreamerv3" / "toy-agent-v0_1"
    with open(tmp_path / "stderr.txt", "w") as errors:
        process = subprocess.Popen(command, env=environment, stdout=subprocess.DEVNULL, stderr=errors)
        try:
            deadline = time.monotonic() + 300
            while not (run / "toy-agent-v0" / "checkpoints" / "latest.json").exists() and time.monotonic() < deadline:
                assert process.poll() is None, (tmp_path / "stderr.txt").read_text()
                time.sleep(0.1)
            process.send_signal(signal.SIGINT)
            process.wait(timeout=120)
        finally:
            process.kill()
    stderr = (tmp_path / "stderr.txt").read_text()
    assert process.returncode == 130, stderr
    assert re.search(
        rf"sb3-ef train: interrupted: stopped at step \d+, model saved to {run}/toy-agent-v0.zip; its last "
        rf"checkpoint is at step \d+: continue with `sb3-ef train --resume {run}`",
        stderr,
    ), stderr
    from sb3_ef.dreamerv3 import DreamerV3

    assert DreamerV3.load(run / "toy-agent-v0.zip", device="cpu").num_timesteps >= 5
