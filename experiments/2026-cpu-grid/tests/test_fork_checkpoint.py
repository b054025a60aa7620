"""fork_checkpoint.py continues a grid run's checkpoint under changed settings, with the control."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

from sb3_ef.common.checkpoints import ResumableCheckpointCallback
from sb3_ef.drqv2 import DrQv2EF
from sb3_ef.grid.grid import constructor_kwargs
from sb3_ef.grid.run import build_env

HERE = Path(__file__).resolve().parents[1]
SCRIPT = HERE / "fork_checkpoint.py"
TINY_GRID = HERE.parents[1] / "tests" / "grid" / "tiny_grid.yml"


def load_script():
    sys.path.insert(0, str(SCRIPT.parent))  # as when the script runs: it imports ef_gradients beside it
    spec = importlib.util.spec_from_file_location("fork_checkpoint", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_forks_continue_the_checkpoint_with_and_without_the_change(tmp_path, capsys):
    script = load_script()
    spec = script.find_run(str(TINY_GRID), "drqv2_ef/dmc-cartpole-balance-v0_s0")
    model = DrQv2EF(env=build_env(spec, seed=0), seed=0, **constructor_kwargs(dict(spec.hyperparams)))
    model.learn(70, callback=ResumableCheckpointCallback(60, str(tmp_path)))
    checkpoint = str(tmp_path / "rl_model_60_steps.zip")
    script.main([str(TINY_GRID), spec.run_id, "--checkpoint", checkpoint, "--variant", "beta=0", "--steps", "20",
                 "--seeds", "3", "--eval-episodes", "1"])  # fmt: skip
    lines = [script.json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [line["settings"] for line in lines] == [{}, {"beta": 0}]  # the control first
    assert all(line["from_step"] == 60 and line["step"] == 80 and line["fork_seed"] == 3 for line in lines)
    assert all(0 <= line["return"] <= 40 for line in lines)  # 40-step episodes, rewards in [0, 1]


def test_fresh_forks_build_each_variant_and_diagnose_it(capsys):
    script = load_script()
    run_id = "drqv2_ef/dmc-cartpole-balance-v0_s0"
    script.main([str(TINY_GRID), run_id, "--variant", "beta=0", "babbling_steps=0", "--variant", "ef_horizon=2",
                 "--steps", "60", "--seeds", "1", "--eval-episodes", "1", "--diagnose"])  # fmt: skip
    lines = [script.json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [line["settings"] for line in lines] == [{}, {"beta": 0, "babbling_steps": 0}, {"ef_horizon": 2}]
    assert all(line["from_step"] == 0 and line["step"] == 60 for line in lines)
    assert all(0.5 <= line["action_majority"] <= 1 and line["encoder_grad_norm_critic"] > 0 for line in lines)
    assert lines[1]["beta_ef_loss"] == 0 and lines[0]["beta_ef_loss"] > 0  # the variant was set before training


def test_bad_input_is_named(capsys):
    script = load_script()
    with pytest.raises(SystemExit, match="has no run 'drqv2_ef/nope_s0'"):
        script.find_run(str(TINY_GRID), "drqv2_ef/nope_s0")
    with pytest.raises(SystemExit):
        script.main([str(TINY_GRID), "drqv2_ef/dmc-cartpole-balance-v0_s0", "--skip-control"])
    assert "--skip-control needs at least one --variant" in capsys.readouterr().err
    with pytest.raises(script.argparse.ArgumentTypeError, match="Expected NAME=VALUE"):
        script.parse_setting("beta")
    with pytest.raises(script.argparse.ArgumentTypeError, match="Python literal"):
        script.parse_setting("beta=zero")
