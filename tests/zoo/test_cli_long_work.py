"""``sb3-ef`` for long work: arguments checked before the heavy imports (fast answers), the full ``train --help``,
progress lines, Ctrl-C that stops and saves, and ``--resume`` from the furthest intact point of a run."""

from __future__ import annotations

import argparse
import os
import shutil
import signal
import statistics
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sb3_ef import DrQv2EF, cli
from sb3_ef.common.checkpoints import latest_checkpoint
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.zoo.options import ENJOY_OPTIONS, TRAIN_OPTIONS, Option, rl_zoo3_parser
from tests.helpers.zoo import ENV_KWARGS, HYPERPARAMS, cli_pairs

COMMANDS = ("train", "enjoy", "optimize", "analyze", "benchmark", "collect", "pretrain", "predict")
#: Generous bound on the answer to a bad argument (the target is under 3 s on a quiet machine).
FAST_ANSWER_S = 6.0


def as_options(parser: argparse.ArgumentParser) -> set[tuple[tuple[str, ...], str, tuple[str, ...] | None]]:
    kinds = set()
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction):
            continue
        if action.nargs == 0:
            kind = "flag"
        elif action.nargs == "+":
            kind = "pairs" if type(action).__name__ == "StoreDict" else "list"
        else:
            kind = "int" if action.type is int else "str"
        choices = None if action.dest == "algo" or action.choices is None else tuple(action.choices)
        kinds.add((tuple(action.option_strings), kind, choices))
    return kinds


def table(options: tuple[Option, ...]) -> set[tuple[tuple[str, ...], str, tuple[str, ...] | None]]:
    return {(option.names, option.kind, option.choices) for option in options}


def test_option_tables_match_rl_zoo3s_parsers():
    from rl_zoo3 import enjoy, train

    assert table(TRAIN_OPTIONS) == as_options(rl_zoo3_parser(train, "train"))
    assert table(ENJOY_OPTIONS) == as_options(rl_zoo3_parser(enjoy, "enjoy"))


def test_train_help_names_the_command_and_sb3_efs_options(capsys):
    assert cli.main(["train", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: sb3-ef train")
    for option in ("--resume", "--checkpoint-buffer", "--keep-checkpoints", "--hyperparams", "--eval-episodes"):
        assert option in out


def answer_seconds(command: str) -> float:
    start = time.perf_counter()
    result = subprocess.run(["sb3-ef", command, "--bad-arg"], capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    assert result.returncode == 2, result.stderr
    assert result.stderr.strip().splitlines()[-1].startswith(f"sb3-ef {command}: error:"), result.stderr
    return elapsed


@pytest.mark.parametrize("command", COMMANDS)
def test_a_bad_argument_is_answered_before_the_heavy_imports(command):
    assert statistics.median(answer_seconds(command) for _ in range(3)) < FAST_ANSWER_S


def test_progress_lines_come_every_interval(capsys):
    from sb3_ef.zoo.progress import ProgressLogCallback

    model = DrQv2EF(
        "CnnPolicy", ToyAgentEnv(size=32, max_episode_steps=5), buffer_size=100, batch_size=4, learning_starts=50,
        ef_horizon=3, babbling_steps=0, device="cpu",
        policy_kwargs={"net_arch": [8], "trunk_dim": 8, "features_dim": 16, "agent_dim": 4,
                       "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}},
    )  # fmt: skip
    with pytest.warns(UserWarning, match="no gradient update will run"):  # rollouts only: progress is what counts
        model.learn(12, callback=ProgressLogCallback(12, interval_s=0.0))
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == "Training from step 0 to 12"
    steps = [line for line in lines if line.startswith("step ")]
    assert len(steps) == 12 and steps[-1].startswith("step 12/12 (100.0%)")
    assert "return" in steps[-1]  # episodes of 5 steps ended


def test_progress_lines_give_the_recent_speed_and_the_time_left_at_it():
    """A fast random-action warm-up (64 steps/s for a minute) then training at 15 steps/s: two minutes on, the
    line gives 15 steps/s and the time left at that speed, not the mean since the start (31 steps/s)."""
    from sb3_ef.zoo.progress import ProgressLogCallback

    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=100, ef_horizon=3, device="cpu")
    callback = ProgressLogCallback(100_000, recent_s=60.0)
    callback.init_callback(model)
    callback.on_training_start({}, {})
    start = callback._start_time
    for second in range(10, 190, 10):
        callback.num_timesteps = 64 * min(second, 60) + 15 * max(0, second - 60)
        line = callback.line(start + second)
    assert callback.num_timesteps == 5640
    assert "  15 steps/s  elapsed 0:03:00  left ~1:44:51" in line  # (100000 - 5640) / 15 s


def test_plan_table_says_when_hours_are_unknown(tmp_path):
    from sb3_ef.grid import grid_runs
    from sb3_ef.grid.runner import plan_table

    runs = grid_runs(["drqv2"], ["dmc/cartpole-balance-v0"], seeds=2, eval_freq=1000, n_timesteps=2000)
    text = plan_table(runs, tmp_path)
    total = next(line for line in text.splitlines() if line.startswith("total"))
    assert total.split()[-1] == "-"  # unknown, not 0.0
    assert "expected hours unknown for drqv2: give each algorithm steps_per_second" in text


def tiny_train_argv(log_folder: Path, *extra: str) -> list[str]:
    algo = "drqv2_ef"
    return [
        "train", "--algo", algo, "--env", "dmc/cartpole-swingup-v0", "-f", str(log_folder), "--seed", "0",
        "--eval-freq", "-1", "--num-threads", "1",
        "--env-kwargs", *cli_pairs(ENV_KWARGS[algo]),
        "--hyperparams", *cli_pairs(HYPERPARAMS[algo]), *extra,
    ]  # fmt: skip


def test_resume_continues_a_finished_run_from_its_final_model(tmp_path):
    """A run trained to 60 steps with checkpoints every 20: --resume -n 80 must start at 60 (the final model), not
    at the newest checkpoint."""
    from sb3_ef.zoo import train

    logs = tmp_path / "logs"
    assert cli.main(tiny_train_argv(logs, "-n", "60", "--save-freq", "20", "--verbose", "0")) == 0
    run = logs / "drqv2_ef" / "dmc-cartpole-swingup-v0_1"
    for checkpoint in run.glob("rl_model_*60_steps.*"):
        checkpoint.unlink()  # one at the last step, if any: the run's newest checkpoint comes before its end
    assert latest_checkpoint(run).step < 60
    argv = train.resume_argv(str(run), ["-n", "80"])
    assert argv[argv.index("-i") + 1] == str(run / "dmc-cartpole-swingup-v0.zip")
    assert cli.main(["train", "--resume", str(run), "-n", "80"]) == 0
    assert DrQv2EF.load(run / "dmc-cartpole-swingup-v0.zip", buffer_size=64).num_timesteps == 80


def test_ctrl_c_in_train_saves_the_model_prints_one_line_and_exits_130(tmp_path, monkeypatch, capsys):
    """Ctrl-C during ``learn`` (raised by the model's first rollout): rl-zoo3 saves the model, then the command
    says what was kept and how to continue, on one line, with exit status 130."""
    from sb3_ef.drqv2 import drqv2

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(drqv2.DrQv2, "collect_rollouts", interrupted)
    logs = tmp_path / "logs"
    assert cli.main(tiny_train_argv(logs, "-n", "100")) == cli.INTERRUPTED_STATUS == 130
    run = logs / "drqv2_ef" / "dmc-cartpole-swingup-v0_1"
    assert (run / "dmc-cartpole-swingup-v0.zip").is_file()
    [line] = [line for line in capsys.readouterr().err.splitlines() if "interrupted" in line]
    assert line == (
        f"sb3-ef train: interrupted: stopped at step 0, model saved to {run}/dmc-cartpole-swingup-v0.zip; "
        f"continue with `sb3-ef train --resume {run}`"
    )


@pytest.mark.slow
def test_ctrl_c_stops_train_within_seconds_and_saves_model_and_buffer(tmp_path):
    """A real ``sb3-ef train`` subprocess (output to a pipe, ``-P`` given) gets SIGINT while training."""
    logs = tmp_path / "logs"
    argv = tiny_train_argv(logs, "-n", "100000", "--save-freq", "1000", "--checkpoint-buffer", "-P")
    environment = {**os.environ, "OMP_NUM_THREADS": "1"}
    process = subprocess.Popen(
        [shutil.which("sb3-ef"), *argv], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=environment
    )
    output = []
    assert process.stdout is not None
    for line in process.stdout:
        output.append(line)
        if line.startswith("Training from step 0"):
            break
    time.sleep(3.0)  # into the updates (learning_starts 40)
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    stopped_s = None
    for line in process.stdout:
        output.append(line)
        if line.startswith("Stopped at step") and stopped_s is None:
            stopped_s = time.monotonic() - sent  # training has stopped and the checkpoint is written
    process.wait(timeout=60)
    exited_s = time.monotonic() - sent
    text = "".join(output)
    assert process.returncode == 130, text
    assert text.rstrip().splitlines()[-1].startswith("sb3-ef train: interrupted: stopped at step")
    assert stopped_s is not None and stopped_s < 5.0, f"{stopped_s} s to stop:\n{text}"
    run = logs / "drqv2_ef" / "dmc-cartpole-swingup-v0_1"
    model = DrQv2EF.load(run / "dmc-cartpole-swingup-v0.zip", buffer_size=64)
    assert 40 < model.num_timesteps < 100_000
    [buffer] = run.glob(f"rl_model_replay_buffer_{model.num_timesteps}_steps.pkl")
    assert buffer.stat().st_size > 0
    assert f"Stopped at step {model.num_timesteps} of 100000" in text
    print(f"SIGINT: stopped and checkpointed after {stopped_s:.2f} s, exited after {exited_s:.2f} s", file=sys.stderr)
