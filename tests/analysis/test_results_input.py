"""`sb3-ef analyze results` on bad input: one clear error, and nothing written."""

from __future__ import annotations

import re

import pytest

from sb3_ef import cli
from sb3_ef.analysis.cli import main
from sb3_ef.analysis.metrics import load_records
from sb3_ef.analysis.records import RECORD_COLUMNS

HEADER = ",".join(RECORD_COLUMNS)
GOOD_ROWS = ["A,dmc/walker-walk-v0,0,0,0,1.5,", "A,dmc/walker-walk-v0,0,100,200,30.0,"]


def write_csv(folder, rows, name="run.csv"):
    folder.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text("\n".join([HEADER, *rows]) + "\n")
    return folder / name


def run_cli(argv, capsys, monkeypatch):
    monkeypatch.delenv("SB3_EF_TRACEBACK", raising=False)
    status = cli.main(argv)
    captured = capsys.readouterr()
    return status, captured.err


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("A,dmc/walker-walk-v0,0,200,400,abc,", r"line 4: return 'abc', expected a finite number"),
        ("A,dmc/walker-walk-v0,0,200,400,,", r"line 4: return '', expected a finite number"),
        ("A,dmc/walker-walk-v0,0,2.5e2x,400,3.0,", r"line 4: step '2.5e2x', expected a whole number of agent steps"),
        ("A,dmc/walker-walk-v0,0,-100,400,3.0,", r"line 4: step '-100', expected a whole number of agent steps >= 0"),
        ("A,dmc/walker-walk-v0,0,200,400.5,3.0,", r"line 4: frame '400.5', expected a whole number of frames"),
        ("A,dmc/walker-walk-v0,0,200,400,3.0,yes", r"line 4: success 'yes', expected empty or a success rate"),
        ("A,dmc/walker-walk-v0,0,200,400,3.0,1.5", r"line 4: success '1.5', expected empty or a success rate"),
        (",dmc/walker-walk-v0,0,200,400,3.0,", r"line 4: algo '', expected a name"),
    ],
)
def test_a_malformed_record_is_one_clear_error_and_nothing_is_written(row, message, tmp_path, capsys, monkeypatch):
    path = write_csv(tmp_path / "runs", [*GOOD_ROWS, row])
    expected = re.escape(str(path)) + " holds values that are not evaluation records: " + message
    with pytest.raises(ValueError, match=expected):
        load_records(tmp_path / "runs")
    status, err = run_cli(["analyze", "results", str(tmp_path / "runs")], capsys, monkeypatch)
    assert status == 2 and "Traceback" not in err
    [line] = err.strip().splitlines()
    assert line.startswith("sb3-ef analyze: error: ") and re.search(message, line)
    assert sorted(path.name for path in (tmp_path / "runs").iterdir()) == ["run.csv"]  # no analysis/ folder


def test_every_bad_column_is_named_with_a_count(tmp_path):
    write_csv(tmp_path, [*GOOD_ROWS, "A,t,0,x,400,abc,", "A,t,0,y,400,def,"])
    with pytest.raises(ValueError, match=r"line 4: step 'x'.* \(and 1 more\); line 4: return 'abc'.* \(and 1 more\)"):
        load_records(tmp_path)


def test_records_are_read_as_numbers(tmp_path):
    write_csv(tmp_path / "a", GOOD_ROWS)
    write_csv(tmp_path / "b", ["B,metaworld/hammer-v3,,0,0,1.0,0.5", "B,metaworld/hammer-v3,,10,20,2.0,"])
    records = load_records(tmp_path).sort_values(["algo", "step"])
    assert records["step"].tolist() == [0, 100, 0, 10] and records["frame"].dtype.kind == "i"
    assert records["return"].tolist() == [1.5, 30.0, 1.0, 2.0]
    assert records["success"].iloc[2] == 0.5 and records["success"].isna().sum() == 3
    assert records["seed"].iloc[:2].tolist() == [0, 0] and records["seed"].iloc[2:].isna().all()


def test_a_records_file_without_rows_is_named(tmp_path):
    write_csv(tmp_path, [])
    with pytest.raises(ValueError, match=r"hold no evaluation yet: \[.*run.csv'\]"):
        load_records(tmp_path)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--reps", "0"], r"reps \(--reps\) must be a positive number of bootstrap resamples, got 0"),
        (["--reps", "-5"], r"got -5"),
        (["--return-scale", "0"], r"return_scale \(--return-scale\) must be positive, got 0.0"),
        (["--at", "-10"], r"Steps \(--at\) must be non-negative agent steps, got \[-10\]"),
    ],
)
def test_bad_options_are_refused_before_anything_is_written(options, message, tmp_path, capsys, monkeypatch):
    write_csv(tmp_path / "runs", GOOD_ROWS)
    status, err = run_cli(["analyze", "results", str(tmp_path / "runs"), *options], capsys, monkeypatch)
    assert status == 2 and "Traceback" not in err and re.search(message, err)
    assert [path.name for path in (tmp_path / "runs").iterdir()] == ["run.csv"]


def test_an_output_path_that_is_a_file_is_refused(tmp_path):
    write_csv(tmp_path / "runs", GOOD_ROWS)
    (tmp_path / "out").write_text("mine")
    with pytest.raises(ValueError, match=r"The output folder .*out' is a file"):
        main(["results", str(tmp_path / "runs"), "--out", str(tmp_path / "out")])
    assert (tmp_path / "out").read_text() == "mine"


def test_good_records_give_every_file_and_no_temporary_is_left(tmp_path):
    write_csv(tmp_path / "runs", GOOD_ROWS)
    assert main(["results", str(tmp_path / "runs"), "--reps", "10", "--at", "100"]) == 0
    written = sorted(path.name for path in (tmp_path / "runs" / "analysis").iterdir())
    assert written == ["curve_dmc_walker-walk-v0.png", "returns_at.csv", "rliable.csv", "rliable.png", "scores.csv"]


def test_steps_past_every_run_are_refused_with_the_last_step(tmp_path, capsys, monkeypatch):
    write_csv(tmp_path / "runs", GOOD_ROWS)
    status, err = run_cli(["analyze", "results", str(tmp_path / "runs"), "--at", "999999"], capsys, monkeypatch)
    assert status == 2 and "Traceback" not in err
    assert "Steps (--at) [999999] lie past the last step of every run" in err and "pick a step <= 100" in err
    assert [path.name for path in (tmp_path / "runs").iterdir()] == ["run.csv"]


def test_runs_that_end_before_a_step_are_named(tmp_path, capsys):
    write_csv(tmp_path, [*GOOD_ROWS, "A,dmc/walker-walk-v0,1,0,0,2.0,", "A,dmc/walker-walk-v0,1,50,100,9.0,"])
    assert main(["results", str(tmp_path), "--reps", "10", "--at", "100", "70"]) == 0
    printed = capsys.readouterr().out
    assert "Left out at step 100 (--at), ended before it: A on dmc/walker-walk-v0 seed 1 (last step 50)" in printed
    assert "No run was evaluated at step(s) [70] exactly: returns_at.csv has no row there" in printed


FRAMELESS = "algo,task,seed,step,return,success\nA,dmc/walker-walk-v0,0,0,1.5,\n"


def test_a_csv_without_the_frame_column_is_skipped_with_a_warning(tmp_path, capsys):
    write_csv(tmp_path / "good", GOOD_ROWS)
    (tmp_path / "old.csv").write_text(FRAMELESS)
    assert main(["results", str(tmp_path), "--reps", "10"]) == 0
    printed = capsys.readouterr().out
    assert re.search(r"Warning: skipped .*old.csv \(columns \['algo', .*'success'\], missing \['frame'\]\)", printed)


def test_nothing_readable_names_the_skipped_csv(tmp_path, capsys, monkeypatch):
    (tmp_path / "old.csv").write_text(FRAMELESS)
    status, err = run_cli(["analyze", "results", str(tmp_path)], capsys, monkeypatch)
    assert status == 2 and "Traceback" not in err
    assert re.search(r"skipped, without that header: .*old.csv \(columns .*missing \['frame'\]\)", err)


def test_algorithms_without_a_shared_task_are_named_with_their_tasks(tmp_path, capsys):
    write_csv(tmp_path / "a", GOOD_ROWS)
    write_csv(tmp_path / "b", [row.replace("A,dmc/walker-walk-v0", "B,dmc/cheetah-run-v0") for row in GOOD_ROWS])
    assert main(["results", str(tmp_path), "--reps", "10"]) == 0
    printed = capsys.readouterr().out
    assert "no task has results of every algorithm; tasks per algorithm: " in printed
    assert "{'A': ['dmc/walker-walk-v0'], 'B': ['dmc/cheetah-run-v0']}" in printed
    written = sorted(path.name for path in (tmp_path / "analysis").iterdir())
    assert written == ["curve_dmc_cheetah-run-v0.png", "curve_dmc_walker-walk-v0.png", "scores.csv"]
