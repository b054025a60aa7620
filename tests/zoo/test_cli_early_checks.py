"""Mistakes ``sb3-ef train`` / ``optimize`` / ``enjoy`` name before the heavy imports (an unknown algorithm or env id,
checkpoint options without checkpoints) or with the cure (a ``--hyperparams`` string without quotes), and Ctrl-C at
the top level as one line."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from sb3_ef import cli
from sb3_ef.zoo.config import ZOO_ALGORITHMS
from sb3_ef.zoo.options import RL_ZOO3_ALGORITHMS

#: Generous bound on the answer (about 0.7 s at load 4 on 2 cores; the heavy imports alone take 4 s or more).
FAST_ANSWER_S = 5.0
HEAVY = ("torch", "stable_baselines3", "rl_zoo3")


def test_the_algorithm_table_matches_rl_zoo3s():
    from rl_zoo3 import utils

    assert set(RL_ZOO3_ALGORITHMS) == set(utils.ALGOS) - set(ZOO_ALGORITHMS)  # sb3-ef's keys are added in place


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--algo", "drqv2_eff"], "Unknown algorithm 'drqv2_eff' (did you mean 'drqv2_ef' or 'drqv2'?)"),
        (["optimize", "--algo", "tdmpc3", "--env", "dmc/cheetah-run-v0"], "Unknown algorithm 'tdmpc3' (did you mean"),
        (
            ["train", "--algo", "drqv2_ef", "--env", "dmc/cartpole-swingup-v9"],
            "Unknown env id 'dmc/cartpole-swingup-v9' (did you mean 'dmc/cartpole-swingup-v0'",
        ),
        (["enjoy", "--algo", "sac_ef", "--env", "dmc/cheetah-rn-v0"], "Unknown env id 'dmc/cheetah-rn-v0' (did you"),
        (["train", "--algo", "sear", "--gym-packages", "no_such_package"], "--gym-packages: cannot import"),
        (["train", "--algo", "sear", "--save-freq", "0"], "--save-freq must be >= 1 (or -1), got 0"),
        (
            ["train", "--algo", "drqv2", "--env", "dmc/cartpole-balance-v0", "--hyperparams", "n_envs:0"],
            "--hyperparams n_envs must be a positive integer (the number of envs stepped together), got 0",
        ),
        (
            ["train", "--algo", "sear", "--checkpoint-buffer"],
            "--checkpoint-buffer: options of the --save-freq checkpoints, give --save-freq N too",
        ),
    ],
)
def test_mistakes_are_answered_before_the_heavy_imports(argv, message):
    probe = (
        "import sys\nfrom sb3_ef import cli\n"
        f"status = cli.main({argv!r})\n"
        f"print(status, *(name in sys.modules for name in {HEAVY!r}))\n"
    )
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    elapsed = time.perf_counter() - start
    assert result.stdout.split() == ["2", "False", "False", "False"], result.stderr
    [line] = result.stderr.splitlines()
    assert line.startswith(f"sb3-ef {argv[0]}: error: {message}"), line
    assert elapsed < FAST_ANSWER_S, f"{elapsed:.1f} s"


@pytest.mark.parametrize(("option", "key"), [("--hyperparams", "coefficients"), ("--env-kwargs", "camera")])
def test_a_string_value_without_quotes_names_the_key_and_the_cure(tmp_path, capsys, monkeypatch, option, key):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    argv = ["train", "--algo", "sear", "--env", "dmc/cartpole-swingup-v0", "-f", str(tmp_path)]
    assert cli.main([*argv, option, f"{key}:bogus"]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line == (
        f"sb3-ef train: error: {option} {key}: cannot evaluate 'bogus' (NameError: name 'bogus' is not "
        f"defined); values are Python expressions, so a string needs quotes: {key}:\"'bogus'\""
    )
    assert not any(tmp_path.iterdir())  # nothing was started


def test_ctrl_c_at_the_top_level_is_one_line(capsys, monkeypatch):
    """A command that does not stop by itself (here ``upgrade``, interrupted at once)."""

    def interrupted(argv):
        raise KeyboardInterrupt

    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    monkeypatch.setattr("sb3_ef.upgrade.main", interrupted)
    assert cli.main(["upgrade", "old.zip", "new.zip"]) == cli.INTERRUPTED_STATUS == 130
    assert capsys.readouterr().err == "\nsb3-ef upgrade: interrupted\n"
