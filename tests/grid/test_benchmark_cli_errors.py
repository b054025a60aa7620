"""``sb3-ef benchmark`` on bad input: one line naming the file and line of a broken YAML (before the heavy imports),
counts refused by the parser before the grid is read."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest

from sb3_ef import cli

#: Generous bound on the answer to a broken grid file (no torch import: about 0.5 s on a quiet machine).
FAST_ANSWER_S = 5.0

BROKEN = "grids:\n  - algorithms: [drqv2\n    tasks: [dmc/cartpole-balance-v0]\n"


def test_a_broken_yaml_is_one_line_naming_file_line_and_column(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    grid = tmp_path / "grid.yml"
    grid.write_text(BROKEN)
    assert cli.main(["benchmark", str(grid), "--out", str(tmp_path / "out")]) == 2
    [line] = capsys.readouterr().err.splitlines()
    assert line == (
        f"sb3-ef benchmark: error: {grid}, line 3, column 10: not valid YAML: expected ',' or ']', but got ':' "
        "(while parsing a flow sequence at line 2, column 17)"
    )
    assert not (tmp_path / "out").exists()


def test_a_broken_yaml_is_answered_before_torch_is_imported(tmp_path):
    grid = tmp_path / "grid.yml"
    grid.write_text(BROKEN)
    probe = (
        "import sys\nfrom sb3_ef import cli\n"
        f"status = cli.main(['benchmark', {str(grid)!r}, '--out', {str(tmp_path / 'out')!r}])\n"
        "print(status, 'torch' in sys.modules, 'stable_baselines3' in sys.modules)\n"
    )
    start = time.perf_counter()
    result = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    assert result.stdout.split() == ["2", "False", "False"], result.stderr
    assert time.perf_counter() - start < FAST_ANSWER_S


@pytest.mark.parametrize(
    ("option", "message"),
    [
        (["--workers", "0"], "argument --workers: must be >= 1, got 0"),
        (["--threads", "-2"], "argument --threads: must be >= 1, got -2"),
        (["--retries", "-1"], "argument --retries: must be >= 0, got -1"),
        (["--gpus", "nan"], "argument --gpus: must be >= 0, got nan"),
        (["--workers", "two"], "argument --workers: expected an integer, got 'two'"),
    ],
)
def test_bad_counts_are_refused_before_the_grid_is_read(tmp_path, capsys, option, message):
    with pytest.raises(SystemExit) as raised:
        cli.main(["benchmark", str(tmp_path / "missing.yml"), "--out", str(tmp_path), *option])
    assert raised.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1] == f"sb3-ef benchmark: error: {message}"


def test_a_results_folder_that_is_a_file_is_refused(tmp_path, capsys):
    out = tmp_path / "results"
    out.write_text("")
    assert cli.main(["benchmark", str(tmp_path / "grid.yml"), "--out", str(out)]) == 2
    assert capsys.readouterr().err == (
        f"sb3-ef benchmark: error: --out {str(out)!r} is a file: expected the results folder (created when missing)\n"
    )
