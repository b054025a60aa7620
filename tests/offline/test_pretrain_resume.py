"""``pretrain`` reruns: settings a run cannot train with, resumed runs with other settings, damaged checkpoints,
full disks and Ctrl-C."""

from __future__ import annotations

import re

import pytest
import torch as th

from sb3_ef.cli import main
from sb3_ef.offline.episodes import write_episode
from sb3_ef.offline.pretrain import CHECKPOINT, MODEL, pretrain
from tests.helpers.offline import TINY_DRQV2, square_episode, tiny_pretrain
from tests.offline.helpers import interrupt_when, run_with_file_size_limit, sb3_ef_process

TINY_EF = {"rollout_hidden_dims": (32,), "decoder_channels": 16}
CLI = ["--encoder", "drqv2", "--context", "2", "--horizon", "3", "--batch-size", "4", "--holdout", "1"]
CLI += [
    "--encoder-kwargs",
    '{"features_dim": 64}',
    "--ef-kwargs",
    '{"rollout_hidden_dims": [32], "decoder_channels": 16}',
]
CLI += ["--agent-dim", "8", "--no-progress"]


@pytest.fixture
def data(tmp_path):
    folder = tmp_path / "data"
    for seed in range(3):
        write_episode(folder / f"episode_{seed}.npz", square_episode(steps=10, seed=seed))
    return folder


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    try:
        status = main(argv)
    except SystemExit as stop:
        status = stop.code
    return status, capsys.readouterr().err


@pytest.mark.parametrize("steps", [-3, 0])
def test_steps_below_one_are_refused_before_anything_is_written(data, tmp_path, steps, capsys):
    with pytest.raises(ValueError, match=rf"steps \(--steps\) must be an integer >= 1, got {steps}"):
        tiny_pretrain(data, tmp_path / "run", steps=steps, overwrite=True)
    status, err = run_cli(
        ["pretrain", str(data), str(tmp_path / "run"), *CLI, "--steps", str(steps), "--overwrite"], capsys
    )
    assert status == 2 and f"argument --steps: expected a positive integer, got {steps}" in err
    assert not (tmp_path / "run").exists()


def test_a_resumed_run_keeps_its_learning_rate_and_the_refusal_names_the_options(data, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["pretrain", str(data), str(run), *CLI, "--steps", "2", "--checkpoint-every", "1"]) == 0
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--steps", "4", "--lr", "0.0005"], capsys)
    assert status == 2 and "Traceback" not in err
    (line,) = [line for line in err.splitlines() if line.startswith("sb3-ef pretrain: error:")]
    assert re.search(r"checkpoint.pt was trained with learning_rate 0.001 \(--lr\), not 0.0005: .*--no-resume", line)
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--steps", "4", "--agent-dim", "16"], capsys)
    assert status == 2 and "agent_dim 8 (--agent-dim), not 16" in err
    assert th.load(run / CHECKPOINT, weights_only=True)["step"] == 2  # untouched by the refused runs


def test_bf16_pretraining_is_recorded_and_resumed_only_in_bf16(data, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["pretrain", str(data), str(run), *CLI, "--steps", "2", "--precision", "bf16"]) == 0
    assert th.load(run / CHECKPOINT, weights_only=True)["training"]["precision"] == "bf16"
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--steps", "4"], capsys)
    assert status == 2 and "precision 'bf16' (--precision), not 'fp32'" in err
    assert main(["pretrain", str(data), str(run), *CLI, "--steps", "4", "--precision", "bf16"]) == 0
    assert th.load(run / MODEL, weights_only=True)["step"] == 4
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--precision", "fp16"], capsys)
    assert status == 2 and "argument --precision: invalid choice: 'fp16'" in err


def test_a_damaged_checkpoint_or_model_is_one_line_never_a_traceback(data, tmp_path, capsys):
    run = tmp_path / "run"
    tiny_pretrain(data, run, steps=2)
    (run / CHECKPOINT).write_bytes((run / CHECKPOINT).read_bytes()[:3000])
    (run / MODEL).write_bytes((run / MODEL).read_bytes()[:3000])
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--steps", "4"], capsys)
    assert status == 2 and "Traceback" not in err
    assert re.search(r"error: .*model.pt' is not a readable checkpoint .*: pass overwrite=True .*--overwrite", err)
    status, err = run_cli(["pretrain", str(data), str(run), *CLI, "--steps", "4", "--overwrite"], capsys)
    assert status == 2 and "Traceback" not in err
    assert re.search(r"error: .*checkpoint.pt' is not a readable checkpoint .*: pass resume=False .*--no-resume", err)
    assert main(["pretrain", str(data), str(run), *CLI, "--steps", "4", "--overwrite", "--no-resume"]) == 0
    assert th.load(run / MODEL, weights_only=True)["step"] == 4


def test_a_full_disk_keeps_the_previous_checkpoint(data, tmp_path):
    run = tmp_path / "run"
    tiny_pretrain(data, run, steps=2, ef_kwargs=TINY_EF)
    before = (run / CHECKPOINT).read_bytes()
    arguments = {"horizon": 3, "batch_size": 4, "holdout": 1, "progress_bar": False, "tensorboard": False}
    result = run_with_file_size_limit(
        "from sb3_ef.offline.pretrain import pretrain",
        f"pretrain({str(data)!r}, {str(run)!r}, steps=4, ef_kwargs={TINY_EF!r}, **{ {**arguments, **TINY_DRQV2}!r})",
        limit=20_000,  # smaller than a checkpoint
    )
    assert result.returncode != 0 and "File too large" in result.stderr, result.stderr[-2000:]
    assert (run / CHECKPOINT).read_bytes() == before and th.load(run / CHECKPOINT, weights_only=True)["step"] == 2
    assert sorted(path.name for path in run.iterdir()) == [CHECKPOINT, "metrics.json", MODEL]  # no temporary file


def test_ctrl_c_saves_a_checkpoint_that_a_rerun_continues(data, tmp_path):
    run = tmp_path / "run"
    process = sb3_ef_process("pretrain", str(data), str(run), *CLI, "--steps", "100000", "--checkpoint-every", "1")
    status, err = interrupt_when(process, lambda: (run / CHECKPOINT).exists())
    lines = [line for line in err.splitlines() if line.startswith("sb3-ef pretrain: interrupted")]
    assert status == 130 and "Traceback" not in err and len(lines) == 1, err
    step = th.load(run / CHECKPOINT, weights_only=True)["step"]
    assert f"stopped at step {step} of 100000; {run / CHECKPOINT} saved: rerun the command" in lines[0]
    assert main(["pretrain", str(data), str(run), *CLI, "--steps", str(step + 2)]) == 0
    assert th.load(run / MODEL, weights_only=True)["step"] == step + 2


def test_an_api_setting_that_cannot_train_is_named(data, tmp_path):
    with pytest.raises(ValueError, match=r"learning_rate \(--lr\) must be a number > 0, got -0.1; batch_size"):
        pretrain(data, tmp_path / "run", learning_rate=-0.1, batch_size=0, progress_bar=False)
