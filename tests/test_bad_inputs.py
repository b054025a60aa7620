"""A new user's bad inputs, each answered at once with a clear error (or a warning, when the input is usable but
probably not what was meant) that names what was expected and what was received.

``API_CASES`` go through the Python classes; ``CLI_CASES`` through ``sb3-ef`` (in-process ``sb3_ef.cli.main``), where
each error must be one line on stderr with exit status 2, never a traceback.
"""

from __future__ import annotations

import re
import shutil
import warnings
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import gymnasium as gym
import numpy as np
import pytest
import torch as th

from sb3_ef import SACEF, TDMPC2EF, DrQv2, DrQv2EF, cli, make_env
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv

SIZE = 32
DRQV2_POLICY = {"net_arch": [16], "trunk_dim": 8, "features_dim": 32, "agent_dim": 8,
                "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}}  # fmt: skip
SAC_POLICY = {"net_arch": [16], "normalize_images": False, "features_extractor_class": DrQv2Encoder,
              "features_extractor_kwargs": {"features_dim": 32}}  # fmt: skip
SAC_EF = {"ef_horizon": 3, "agent_dim": 8, "ef_kwargs": {"rollout_hidden_dims": (8,), "decoder_channels": 4}}


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=SIZE, max_episode_steps=20)


def drqv2_ef(**kwargs: Any) -> DrQv2EF:
    arguments = {"buffer_size": 200, "batch_size": 4, "learning_starts": 8, "ef_horizon": 3, "babbling_steps": 0,
                 "policy_kwargs": dict(DRQV2_POLICY), "device": "cpu", **kwargs}  # fmt: skip
    return DrQv2EF("CnnPolicy", toy_env(), **arguments)


def sac_ef(**kwargs: Any) -> SACEF:
    return SACEF("CnnPolicy", toy_env(), buffer_size=200, policy_kwargs=dict(SAC_POLICY), **SAC_EF, **kwargs)


def tdmpc2_ef(**kwargs: Any) -> TDMPC2EF:
    return TDMPC2EF("CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=20), buffer_size=200, **kwargs)


@pytest.fixture(scope="module")
def saved_model(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "model.zip"
    drqv2_ef().save(path)
    return path


class Case(NamedTuple):
    """A bad input: what runs it, and the error (or warning) class and message it must give."""

    name: str
    run: Callable[..., Any]
    error: type[Exception] | type[Warning]
    message: str


def truncated_copy(saved: Path, folder: Path) -> Path:
    damaged = folder / "damaged.zip"
    damaged.write_bytes(saved.read_bytes()[: saved.stat().st_size // 2])
    return damaged


API_CASES = [
    Case(
        "beta as a string",
        lambda: drqv2_ef(beta="1"),
        ValueError,
        r"beta must be a positive number \(use DrQv2 .*\), got str '1'",
    ),
    Case(
        "learning_rate as a string",
        lambda: drqv2_ef(learning_rate="0.001"),
        ValueError,
        r"learning_rate must be a number >= 0 or a schedule .* got str '0.001'",
    ),
    Case(
        "unknown policy name",
        lambda: DrQv2EF("MlpPolicy", toy_env()),
        ValueError,
        r"unknown policy 'MlpPolicy'.*; expected one of 'CnnPolicy' or a policy class",
    ),
    Case("policy name typo", lambda: DrQv2EF("CnnPolcy", toy_env()), ValueError, r"did you mean 'CnnPolicy'"),
    Case("batch_size 0", lambda: drqv2_ef(batch_size=0), ValueError, r"batch_size must be a positive integer, got 0"),
    Case(
        "negative buffer_size", lambda: drqv2_ef(buffer_size=-1), ValueError, r"buffer_size must be a positive integer"
    ),
    Case("gamma above 1", lambda: drqv2_ef(gamma=1.5), ValueError, r"gamma must be a number in \[0, 1\], got 1.5"),
    Case("negative tau", lambda: drqv2_ef(tau=-0.1), ValueError, r"tau must be a number in \[0, 1\]"),
    Case(
        "negative learning_starts",
        lambda: drqv2_ef(learning_starts=-1),
        ValueError,
        r"learning_starts must be >= 0, got -1",
    ),
    Case("ef_horizon 0", lambda: drqv2_ef(ef_horizon=0), ValueError, r"ef_horizon must be a positive integer"),
    Case(
        "negative babbling_steps",
        lambda: drqv2_ef(babbling_steps=-5),
        ValueError,
        r"babbling_steps must be >= 0, got -5",
    ),
    Case(
        "train_freq 0", lambda: drqv2_ef(train_freq=0), ValueError, r"train_freq must be a positive integer or a pair"
    ),
    Case(
        "gradient_steps -2",
        lambda: drqv2_ef(gradient_steps=-2),
        ValueError,
        r"gradient_steps must be an integer >= 0 \(0: collect without training\) or -1",
    ),
    Case(
        "n_steps as a string",
        lambda: drqv2_ef(n_steps="3"),
        ValueError,
        r"n_steps must be a positive integer, got str '3'",
    ),
    Case(
        "device typo", lambda: drqv2_ef(device="cdua"), ValueError, r"device must be 'auto', 'cpu', 'cuda'.*got 'cdua'"
    ),
    Case(
        "SAC-EF beta as a string",
        lambda: sac_ef(beta="1"),
        ValueError,
        r"beta must be a positive number \(use SAC .*\), got str '1'",
    ),
    Case(
        "SAC-EF host argument as a string",
        lambda: sac_ef(learning_rate="3e-4"),
        ValueError,
        r"SACEF: learning_rate must be a number >= 0 or a schedule",
    ),
    Case("SAC-EF unknown policy", lambda: SACEF("CnnPolicyy", toy_env()), ValueError, r"did you mean 'CnnPolicy'"),
    Case(
        "TD-MPC2-EF rho above 1", lambda: tdmpc2_ef(rho=2.0), ValueError, r"TDMPC2EF: rho must be a number in \[0, 1\]"
    ),
    Case(
        "TD-MPC2-EF learning_rate as a string",
        lambda: tdmpc2_ef(learning_rate="3e-4"),
        ValueError,
        r"TDMPC2EF: learning_rate must be",
    ),
    Case(
        "learn(-5)",
        lambda: drqv2_ef().learn(-5),
        ValueError,
        r"total_timesteps must be a whole number of steps >= 0, got -5",
    ),
    Case("learn(2.5)", lambda: drqv2_ef().learn(2.5), ValueError, r"total_timesteps must be a whole number"),
    Case(
        "learning_starts beyond the run",
        lambda: drqv2_ef(learning_starts=100).learn(10),
        UserWarning,
        r"learning_starts=100 is not below the 10 steps this learn call reaches: no gradient update will run",
    ),
    Case(
        "batch_size above buffer_size",
        lambda: drqv2_ef(batch_size=64, buffer_size=32, learning_starts=4).learn(8),
        ValueError,
        r"batch_size=64 exceeds buffer_size=32",
    ),
    Case(
        "predict on float frames",
        lambda: drqv2_ef().predict(np.zeros((9, SIZE, SIZE), np.float32)),
        ValueError,
        r"predict expects uint8 pixel observations .* got an array of dtype float32",
    ),
    Case("load a missing .zip", lambda: DrQv2EF.load("nope.zip"), FileNotFoundError, r"^No saved model at nope.zip$"),
    Case(
        "load a missing name", lambda: DrQv2EF.load("nope"), FileNotFoundError, r"^No saved model at nope or nope.zip$"
    ),
    Case(
        "load a truncated zip",
        lambda saved_model, tmp_path: DrQv2EF.load(truncated_copy(saved_model, tmp_path)),
        ValueError,
        r"damaged.zip is not a saved model: expected a zip archive",
    ),
    Case(
        "plain DrQv2 loads a DrQv2EF zip",
        lambda saved_model: DrQv2.load(saved_model),
        ValueError,
        r"model.zip as DrQv2: it was saved by DrQv2EF, use DrQv2EF.load",
    ),
    Case(
        "TDMPC2EF loads a DrQv2EF zip",
        lambda saved_model: TDMPC2EF.load(saved_model),
        ValueError,
        r"model.zip as TDMPC2EF: it was saved by DrQv2EF, use DrQv2EF.load",
    ),
    Case(
        "env name typo",
        lambda: make_env("dmc/cartpole-swingp"),
        ValueError,
        r"Unknown env name 'dmc/cartpole-swingp' \(did you mean 'dmc/cartpole-swingup'",
    ),
    Case(
        "env option typo through gym.make",
        lambda: gym.make("dmc/cartpole-swingup-v0", fast_rendr=True),
        ValueError,
        r"Unknown env option 'fast_rendr' for dmc/cartpole-swingup \(did you mean 'fast_render'\?\)",
    ),
    Case(
        "Meta-World option on a DMC env",
        lambda: make_env("dmc/cartpole-swingup", resample_task=True),
        ValueError,
        r"Unknown env option 'resample_task' for dmc/cartpole-swingup",
    ),
]


@pytest.mark.parametrize("case", API_CASES, ids=[case.name for case in API_CASES])
def test_api_bad_input_is_answered_clearly(case, request, tmp_path):
    arguments = {name: request.getfixturevalue(name) if name != "tmp_path" else tmp_path
                 for name in case.run.__code__.co_varnames[: case.run.__code__.co_argcount]}  # fmt: skip
    if issubclass(case.error, Warning):
        with pytest.warns(case.error, match=case.message):
            case.run(**arguments)
    else:
        with pytest.raises(case.error, match=case.message):
            case.run(**arguments)


@pytest.mark.skipif(th.cuda.is_available(), reason="the warning is for machines without CUDA")
def test_cuda_asked_without_a_gpu_warns():
    with pytest.warns(UserWarning, match="device='cuda' was asked for but CUDA is not available"):
        drqv2_ef(device="cuda")


def test_channels_last_frames_are_transposed_as_sb3_does():
    """Not a mistake: SB3's predict takes channels-last images (what VecTransposeImage's env gives) and transposes
    them; the action is the channels-first one."""
    model = drqv2_ef()
    observation = model.observation_space.sample()
    first, _ = model.predict(observation, deterministic=True)
    last, _ = model.predict(observation.transpose(1, 2, 0), deterministic=True)
    np.testing.assert_array_equal(first, last)


def run_cli(argv: list[str], capsys) -> tuple[int, str]:
    """``sb3-ef argv`` in this process: exit status and stderr."""
    try:
        status = cli.main(argv)
    except SystemExit as stop:  # argparse's own errors (usage + message)
        status = stop.code
    return status, capsys.readouterr().err


def small_train(*extra: str) -> list[str]:
    return ["train", "--algo", "drqv2_ef", "--env", "dmc/cartpole-swingup-v0", "--seed", "0",
            "--env-kwargs", "size:32", "fast_render:True", *extra]  # fmt: skip


CLI_CASES = [
    Case("train unknown option", lambda: ["train", "--bad-arg"], SystemExit, r"unrecognized arguments: --bad-arg$"),
    Case(
        "train option typo",
        lambda: ["train", "--eval-episdes", "3"],
        SystemExit,
        r"unrecognized arguments: --eval-episdes 3 \(did you mean '--eval-episodes'\?\)",
    ),
    Case(
        "hyperparams with =",
        lambda: ["train", "--hyperparams", "batch_size=32"],
        SystemExit,
        r"expected key:value items \(e.g. batch_size:32\), got 'batch_size=32'",
    ),
    Case(
        "hyperparams not Python",
        lambda: ["train", "--hyperparams", "policy_kwargs:dict(x=1"],
        SystemExit,
        r"policy_kwargs: 'dict\(x=1' is not a Python expression",
    ),
    Case(
        "env-kwargs without value",
        lambda: ["train", "--env-kwargs", "size"],
        SystemExit,
        r"expected key:value items .* got 'size'",
    ),
    Case("negative -n", lambda: ["train", "-n", "-5"], SystemExit, r"--n-timesteps must be >= 1, got -5"),
    Case("-n not a number", lambda: ["train", "-n", "1e5x"], SystemExit, r"invalid int value: '1e5x'"),
    Case(
        "eval-episodes 0", lambda: ["train", "--eval-episodes", "0"], SystemExit, r"--eval-episodes must be >= 1, got 0"
    ),
    Case(
        "log-interval 0", lambda: ["train", "--log-interval", "0"], SystemExit, r"--log-interval must be >= 1 \(or -1\)"
    ),
    Case(
        "keep-checkpoints 0",
        lambda: ["train", "--keep-checkpoints", "0"],
        SystemExit,
        r"--keep-checkpoints must be >= 1",
    ),
    Case("vec-env typo", lambda: ["train", "--vec-env", "dumy"], SystemExit, r"invalid choice: 'dumy'"),
    Case(
        "unknown algorithm",
        lambda: ["train", "--algo", "drqv2ef"],
        SystemExit,
        r"Unknown algorithm 'drqv2ef' \(did you mean 'drqv2_ef'",
    ),
    Case(
        "env id typo",
        lambda: ["train", "--algo", "drqv2_ef", "--env", "dmc/cartpole-swingp-v0"],
        SystemExit,
        r"Unknown env id 'dmc/cartpole-swingp-v0' \(did you mean 'dmc/cartpole-swingup-v0'",
    ),
    Case(
        "hyperparams key typo",
        lambda: small_train("--hyperparams", "batch_sise:32"),
        SystemExit,
        r"unknown key 'batch_sise' for drqv2_ef \(did you mean 'batch_size'\?\)",
    ),
    Case(
        "hyperparams value fails to evaluate",
        lambda: small_train("--hyperparams", "policy_kwargs:dict(x=y)"),
        SystemExit,
        r"--hyperparams policy_kwargs: cannot evaluate 'dict\(x=y\)' \(NameError",
    ),
    Case(
        "optimize without a sampler",
        lambda: ["optimize", "--algo", "sac_ef", "--env", "dmc/cartpole-swingup-v0"],
        SystemExit,
        r"No Optuna sampler for 'sac_ef'",
    ),
    Case(
        "trained agent missing",
        lambda: small_train("-i", "missing.zip"),
        SystemExit,
        r"-i expects the path of a saved model .zip, got 'missing.zip'",
    ),
    Case(
        "resume of a missing folder",
        lambda tmp_path: ["train", "--resume", str(tmp_path / "nope")],
        SystemExit,
        r"--resume expects an sb3-ef run folder .* \(not a folder\)",
    ),
    Case(
        "env option typo",
        lambda tmp_path: small_train("fast_rendr:True", "-f", str(tmp_path)),
        SystemExit,
        r"Unknown env option 'fast_rendr' for dmc/cartpole-swingup \(did you mean 'fast_render'\?\)",
    ),
    Case(
        "learning_rate as a string in the config",
        lambda tmp_path: small_train("-f", str(tmp_path), "--hyperparams", "learning_rate:'0.001'"),
        SystemExit,
        r"--hyperparams: learning_rate must be a number or rl-zoo3's linear schedule 'lin_<initial value>', got "
        r"the string '0.001'",
    ),
    Case(
        "beta as a string in the config",
        lambda tmp_path: small_train("-f", str(tmp_path), "--hyperparams", "beta:'1'"),
        SystemExit,
        r"beta must be a positive number \(use DrQv2 .*\), got str '1'",
    ),
    Case("enjoy unknown option", lambda: ["enjoy", "--bad-arg"], SystemExit, r"unrecognized arguments: --bad-arg"),
    Case(
        "enjoy missing run",
        lambda tmp_path: [
            "enjoy",
            "--algo",
            "drqv2_ef",
            "--env",
            "dmc/cartpole-swingup-v0",
            "-f",
            str(tmp_path),
            "--exp-id",
            "7",
        ],
        SystemExit,
        r"No run dmc-cartpole-swingup-v0_7 under .*drqv2_ef: no run of this env there",
    ),
    Case(
        "analyze results of a missing folder",
        lambda: ["analyze", "results", "no_such_dir"],
        SystemExit,
        r"The results folder 'no_such_dir' does not exist",
    ),
    Case(
        "benchmark keep-checkpoints 0",
        lambda: ["benchmark", "grid.yml", "--out", "x", "--keep-checkpoints", "0"],
        SystemExit,
        r"expected a count >= 1 or 'all', got '0'",
    ),
]


@pytest.mark.parametrize("case", CLI_CASES, ids=[case.name for case in CLI_CASES])
def test_cli_bad_input_is_one_line_and_exit_status_2(case, tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    monkeypatch.chdir(tmp_path)
    argv = case.run(tmp_path) if case.run.__code__.co_argcount else case.run()
    status, err = run_cli(argv, capsys)
    assert status == 2, err
    lines = [line for line in err.splitlines() if line.startswith(f"sb3-ef {argv[0]}: error:")]
    assert len(lines) == 1, err
    assert re.search(case.message, lines[0]), lines[0]
    assert "Traceback" not in err
    assert not any(Path(tmp_path).glob("*/drqv2_ef/*")), "a failed start left a run folder"


def test_the_list_has_at_least_forty_inputs():
    assert len(API_CASES) + len(CLI_CASES) >= 40


def test_resume_passes_over_a_truncated_newest_checkpoint(saved_model, tmp_path):
    from sb3_ef.common.checkpoints import latest_checkpoint

    shutil.copy(saved_model, tmp_path / "rl_model_100_steps.zip")
    (tmp_path / "rl_model_200_steps.zip").write_bytes(saved_model.read_bytes()[:-200])
    with pytest.warns(UserWarning, match=r"rl_model_200_steps.zip is damaged .*: using an older one"):
        checkpoint = latest_checkpoint(tmp_path, intact=True)
    assert checkpoint is not None and checkpoint.model_path.name == "rl_model_100_steps.zip"
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert latest_checkpoint(tmp_path).step == 200  # without intact: what is there, unchecked
    assert zipfile.is_zipfile(tmp_path / "rl_model_100_steps.zip")


OFFLINE_CLI_CASES = [
    Case("pretrain --steps -3", lambda: ["pretrain", "d", "r", "--steps", "-3"], SystemExit,
         r"argument --steps: expected a positive integer, got -3"),
    Case("pretrain --lr 0", lambda: ["pretrain", "d", "r", "--lr", "0"], SystemExit,
         r"argument --lr: expected a positive number, got 0.0"),
    Case("pretrain --holdout 2.5", lambda: ["pretrain", "d", "r", "--holdout", "2.5"], SystemExit,
         r"argument --holdout: expected a count of episodes or a fraction < 1, got 2.5"),
    Case("collect --size 0", lambda: ["collect", "toy/agent-v0", "o", "--size", "0"], SystemExit,
         r"argument --size: expected a positive integer, got 0"),
    Case("predict --steps 0", lambda: ["predict", "m.pt", "o", "--dataset", "d", "--steps", "0"], SystemExit,
         r"argument --steps: expected a positive integer, got 0"),
    Case("predict a missing model", lambda: ["predict", "missing.pt", "o", "--dataset", "d"], FileNotFoundError,
         r"No pretrained model at 'missing.pt'"),
    Case("collect an unknown toy env", lambda: ["collect", "toy/agent-vX", "o", "--no-progress"], ValueError,
         r"Unknown env 'toy/agent-vX': .*Did you mean: `agent`\?"),
]  # fmt: skip


@pytest.mark.parametrize("case", OFFLINE_CLI_CASES, ids=[case.name for case in OFFLINE_CLI_CASES])
def test_offline_cli_bad_input_is_one_line_and_exit_status_2(case, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    argv = case.run()
    status, err = run_cli(argv, capsys)
    lines = [line for line in err.splitlines() if line.startswith(f"sb3-ef {argv[0]}: error:")]
    assert status == 2 and len(lines) == 1 and "Traceback" not in err, err
    assert re.search(case.message, lines[0]), lines[0]
    assert list(tmp_path.iterdir()) == []  # nothing written
