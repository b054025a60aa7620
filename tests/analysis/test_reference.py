"""Published reference curves shipped with the package, and `analyze results --reference` beside them."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_ef.analysis.cli import main as analyze_main
from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.analysis.reference import (
    REFERENCES,
    get_reference,
    load_reference,
    missing_tasks,
    reference_table,
    reference_task,
)
from sb3_ef.grid import load_grid
from sb3_ef.grid.run import execute_run

REPO = Path(__file__).resolve().parents[2]
CPU_GRID_RESULTS = REPO / "experiments" / "2026-cpu-grid" / "results" / "cpu"
TINY_GRID = REPO / "tests" / "grid" / "tiny_grid.yml"


def _records(algo: str, task: str, returns: dict[int, list[float]], action_repeat: int = 2) -> pd.DataFrame:
    """Evaluation records of one algorithm on one task: ``returns[seed]`` at steps 0, 1000, 2000, ..."""
    rows = [
        {"algo": algo, "task": task, "seed": seed, "step": 1000 * i, "frame": 1000 * i * action_repeat,
         "return": value, "success": np.nan}
        for seed, values in returns.items() for i, value in enumerate(values)
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=list(RECORD_COLUMNS))


@pytest.mark.parametrize(
    ("name", "task", "x", "mean", "std", "seeds"),
    [
        # The published tables: DrQ-v2 at 100k frames, TD-MPC2 (pixels) at 100k agent steps.
        ("drqv2", "cartpole-swingup", 100_000, 626, 268, 10),
        ("drqv2", "walker-walk", 100_000, 170, 160, 10),
        ("tdmpc2", "reacher-easy", 100_000, 360, 58, 3),
        ("tdmpc2", "walker-walk", 1_000_000, 940, 10, 3),
    ],
)
def test_shipped_curves_hold_the_published_numbers(name, task, x, mean, std, seeds):
    curves = load_reference(name)
    at = curves[(curves["task"] == task) & (curves["x"] == x)]["return"]
    assert len(at) == seeds
    assert at.mean() == pytest.approx(mean, abs=1) and at.std() == pytest.approx(std, abs=1)


def test_every_reference_names_its_unit_and_source():
    for name, reference in REFERENCES.items():
        assert reference.x_column in ("frame", "step") and "MIT" in reference.source
        assert set(load_reference(name)["task"]) >= {"cartpole-swingup-sparse", "walker-walk", "reacher-easy"}
    with pytest.raises(ValueError, match=r"Unknown reference 'dreamer': expected one of \['drqv2', 'tdmpc2'\]"):
        get_reference("dreamer")


def test_task_names_map_onto_the_references():
    assert reference_task("dmc/cartpole-balance-v0") == "cartpole-balance"
    assert reference_task("dmc/finger_turn_easy") == "finger-turn-easy"
    records = _records("DrQv2", "metaworld/hammer-v3", {0: [1.0]})
    assert missing_tasks(records, "drqv2") == ["metaworld/hammer-v3"]


def test_table_compares_on_the_references_axis():
    # Seeds 0 and 1 on walker-walk; x = agent steps x 2 for DrQ-v2 (frames), agent steps for TD-MPC2.
    records = _records("mine", "dmc/walker-walk-v0", {0: [0, 100, 200], 1: [0, 300, 400]})
    drqv2 = reference_table(records, "drqv2", at=(1000, 2000))
    assert drqv2[["step", "x", "unit", "seeds"]].values.tolist() == [[1000, 2000, "frame", 2], [2000, 4000, "frame", 2]]
    assert drqv2["mean"].tolist() == [200.0, 300.0]
    assert drqv2["std"].iloc[0] == pytest.approx(np.std([100, 300], ddof=1))
    # The official side: each seed interpolated at 4000 frames, independently of the table's code.
    curves = load_reference("drqv2")
    walker = curves[curves["task"] == "walker-walk"]
    expected = [np.interp(4000, run["x"], run["return"]) for _, run in walker.groupby("seed")]
    row = drqv2.iloc[1]
    assert row["official_seeds"] == 10 and row["official_mean"] == pytest.approx(np.mean(expected))
    assert (row["official_min"], row["official_max"]) == pytest.approx((min(expected), max(expected)))
    # Default: the last step every seed reached; TD-MPC2's axis is agent steps.
    tdmpc2 = reference_table(records, "tdmpc2")
    assert tdmpc2[["step", "x", "unit"]].values.tolist() == [[2000, 2000, "step"]]


def test_table_leaves_out_what_the_official_seeds_never_reached():
    records = _records("mine", "dmc/reacher-easy-v0", {0: [0.0] * 3})
    far = reference_table(records, "tdmpc2", at=(5_000_000,))  # past TD-MPC2's last evaluation, and the run's
    assert far["official_seeds"].tolist() == [0] and far["seeds"].tolist() == [0]
    assert np.isnan(far["official_mean"].iloc[0]) and np.isnan(far["mean"].iloc[0])
    with pytest.raises(ValueError, match="Expected non-negative steps, got"):
        reference_table(records, "tdmpc2", at=(-1,))


def test_results_command_puts_the_committed_cpu_grid_beside_drqv2(tmp_path, capsys):
    out = tmp_path / "analysis"
    argv = ["results", str(CPU_GRID_RESULTS), "--finished-only", "--at", "20000", "--reference", "drqv2"]
    assert analyze_main([*argv, "--out", str(out), "--reps", "50"]) == 0
    table = pd.read_csv(out / "reference_drqv2.csv")
    assert len(table) == 4 and set(table["x"]) == {40000} and set(table["seeds"]) == {3}
    balance = table[(table["algo"] == "DrQv2") & (table["task"] == "dmc/cartpole-balance-v0")].iloc[0]
    assert balance["mean"] == pytest.approx(829.3, abs=0.1)  # the grid's own result at 20k steps
    assert balance["official_mean"] == pytest.approx(835, abs=1)  # the published 835 +- 203 at 40k frames
    assert sorted(path.name for path in out.glob("reference_*.png")) == [
        "reference_drqv2_dmc_cartpole-balance-v0.png",
        "reference_drqv2_dmc_cartpole-swingup-v0.png",
    ]
    assert "Against DrQ-v2 (official)" in capsys.readouterr().out


def test_results_command_on_a_fresh_run_beside_the_references(tmp_path, capsys):
    spec = load_grid(TINY_GRID)[0]  # DrQ-v2 on cartpole-balance, 200 agent steps, evaluated at 100 and 200
    execute_run(spec, tmp_path / "runs", threads=1)
    out = tmp_path / "drqv2"
    assert analyze_main(["results", str(tmp_path / "runs"), "--out", str(out), "--reference", "drqv2"]) == 0
    [row] = pd.read_csv(out / "reference_drqv2.csv").to_dict("records")
    assert (row["task"], row["step"], row["x"], row["unit"], row["seeds"]) == ("dmc/cartpole-balance-v0", 200, 400,
                                                                              "frame", 1)  # fmt: skip
    assert row["official_seeds"] == 10
    # TD-MPC2 published no pixel results on cartpole-balance: the task is named and left out.
    capsys.readouterr()
    assert analyze_main(["results", str(tmp_path / "runs"), "--out", str(tmp_path / "t"), "--reference", "tdmpc2"]) == 0
    assert "No TD-MPC2 (official) curves for ['dmc/cartpole-balance-v0']" in capsys.readouterr().out
    assert pd.read_csv(tmp_path / "t" / "reference_tdmpc2.csv").empty
