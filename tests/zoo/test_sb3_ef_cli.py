"""The ``sb3-ef`` console script: help, dispatch of each subcommand with its arguments, unknown commands."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sb3_ef import cli


def test_console_script_help_lists_the_subcommands():
    result = subprocess.run(["sb3-ef", "--help"], capture_output=True, text=True, check=True)
    for command in ("train", "enjoy", "optimize", "analyze"):
        assert command in result.stdout


@pytest.mark.parametrize(
    ("argv", "module", "expected"),
    [
        (["train", "--algo", "drqv2_ef", "-n", "10"], "sb3_ef.zoo.train", ["--algo", "drqv2_ef", "-n", "10"]),
        (["optimize", "--algo", "tdmpc2"], "sb3_ef.zoo.train", ["-optimize", "--algo", "tdmpc2"]),
        (["enjoy", "--algo", "drqv2", "--no-render"], "sb3_ef.zoo.enjoy", ["--algo", "drqv2", "--no-render"]),
    ],
)
def test_subcommands_forward_their_arguments(argv, module, expected, monkeypatch):
    received = []
    __import__(module)
    monkeypatch.setattr(sys.modules[module], "main", received.append)
    cli.main(argv)
    assert received == [expected]


def test_analyze_forwards_to_the_analysis_cli(monkeypatch):
    from sb3_ef.analysis import cli as analysis_cli

    received = []
    monkeypatch.setattr(analysis_cli, "main", received.append)
    assert cli.main(["analyze", "results", "runs/", "--reps", "10"]) == 0
    assert received == [["results", "runs/", "--reps", "10"]]


def test_analyze_exit_status_reaches_the_shell(monkeypatch):
    from sb3_ef.analysis import cli as analysis_cli

    monkeypatch.setattr(analysis_cli, "main", lambda argv: 3)
    assert cli.main(["analyze", "results", "missing/"]) == 3


def test_train_errors_reach_the_user_as_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    assert cli.main(["train", "--algo", "sac_fe", "--env", "dmc/cheetah-run-v0", "-f", str(tmp_path)]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line.startswith("sb3-ef train: error: Unknown algorithm 'sac_fe'")
    monkeypatch.setenv("SB3_EF_TRACEBACK", "1")
    with pytest.raises(ValueError, match="Unknown algorithm 'sac_fe'"):
        cli.main(["train", "--algo", "sac_fe", "--env", "dmc/cheetah-run-v0", "-f", str(tmp_path)])


def test_a_failed_start_leaves_no_run_folder(tmp_path, capsys):
    """net_arch 'big' fails while the model is built, after rl-zoo3 made the run folder: it is removed again."""
    (tmp_path / "drqv2" / "dmc-cartpole-swingup-v0_1").mkdir(parents=True)  # an earlier run stays
    status = cli.main(["train", "--algo", "drqv2", "--env", "dmc/cartpole-swingup-v0", "-f", str(tmp_path),
                       "--env-kwargs", "size:32", "fast_render:True", "--hyperparams", "buffer_size:100",
                       "policy_kwargs:dict(net_arch='big')"])  # fmt: skip
    assert status == 2
    assert "net_arch" in capsys.readouterr().err
    assert [path.name for path in (tmp_path / "drqv2").iterdir()] == ["dmc-cartpole-swingup-v0_1"]
    status = cli.main(["train", "--algo", "drqv2", "--env", "dmc/cartpole-swingup-v0", "-f", str(tmp_path / "new"),
                       "--env-kwargs", "size:32", "fast_render:True", "--hyperparams", "buffer_size:100",
                       "policy_kwargs:dict(net_arch='big')"])  # fmt: skip
    assert status == 2 and not (tmp_path / "new").exists()  # nor the log folders it would have made


def test_version(capsys):
    from sb3_ef import __version__

    with pytest.raises(SystemExit) as raised:
        cli.main(["--version"])
    assert raised.value.code == 0 and capsys.readouterr().out.strip() == f"sb3-ef {__version__}"


@pytest.mark.parametrize("argv", [[], ["tune"]])
def test_missing_or_unknown_command_is_an_error_naming_the_commands(argv, capsys):
    with pytest.raises(SystemExit) as raised:
        cli.main(argv)
    assert raised.value.code == 2
    error = capsys.readouterr().err
    assert "{train,enjoy,optimize,analyze," in error  # the rl-zoo3 and analysis commands come first
    assert "{" + ",".join(cli.COMMANDS) + "}" in error  # and every command is named (offline ones included)
