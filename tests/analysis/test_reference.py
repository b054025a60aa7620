"""Published reference curves shipped with the package, and `analyze results --reference` beside them."""

from __future__ import annotations

import gzip
import json
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sb3_ef.analysis.cli import REFERENCE_NAMES
from sb3_ef.analysis.cli import main as analyze_main
from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.analysis.reference import (
    REFERENCES,
    authors_scores,
    check_reference_data,
    get_reference,
    load_reference,
    missing_tasks,
    official_at,
    reference_table,
    reference_task,
    seed_band,
    unit_warnings,
)
from sb3_ef.analysis.results import analyze_results
from sb3_ef.grid import load_grid
from sb3_ef.grid.run import execute_run

REPO = Path(__file__).resolve().parents[2]
#: A finished benchmark grid's results (tests/analysis/data/README.md): DrQ-v2 and DrQv2-EF on two cartpole tasks.
CPU_GRID_RESULTS = Path(__file__).resolve().parent / "data" / "cpu_grid"
TINY_GRID = REPO / "tests" / "grid" / "tiny_grid.yml"


def installed(name: str) -> bool:
    """Whether the data file of reference ``name`` is installed (the 2023 Dreamer-v3 scores are added by hand)."""
    return (resources.files("sb3_ef.analysis") / "reference_data" / get_reference(name).file).is_file()


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
        # danijar/dreamerv3 scores/dmc_vision-*.json.gz, read from the source files: CURL at 500k and 100k frames,
        # Dreamer-v3 at the 993,984-frame point that 9 of its 10 walker-walk seeds share.
        ("curl", "walker-walk", 500_000, 794.0, 256.3, 10),
        ("curl", "cheetah-run", 100_000, 259.6, 66.4, 10),
        ("dreamerv3", "walker-walk", 993_984, 957.1, 29.1, 9),
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
        assert reference.unit.startswith(reference.axis)
        if installed(name):
            assert set(load_reference(name)["task"]) >= {"cartpole-swingup-sparse", "walker-walk", "reacher-easy"}
    assert sorted(REFERENCE_NAMES) == sorted(REFERENCES)  # the command line offers every reference
    expected = r"Unknown reference 'dreamer': expected one of \['curl', 'dreamerv3', 'dreamerv3-2023', 'drqv2', "
    with pytest.raises(ValueError, match=expected):
        get_reference("dreamer")


def test_both_dreamerv3_score_sets_name_their_version_model_size_and_commit():
    current, paper = get_reference("dreamerv3"), get_reference("dreamerv3-2023")
    assert "2024 release" in current.label and "model 12M" in current.label and "2411f7d" in current.source
    assert "2023 release" in paper.label and "model S" in paper.label and "8fa35f8" in paper.source
    assert (current.x_column, paper.x_column) == ("frame", "frame")
    records = _records("mine", "dmc/walker-walk-v0", {0: [0.0, 10.0]})
    assert set(reference_table(records, "dreamerv3")["reference"]) == {current.label}


@pytest.mark.parametrize(
    ("name", "scores"),
    [
        ("dreamerv3", {"finger-spin": 589, "quadruped-walk": 809, "reacher-hard": 855, "hopper-hop": 227}),
        ("dreamerv3-2023", {"finger-spin": 830, "quadruped-walk": 434, "reacher-hard": 574, "hopper-hop": 383}),
    ],
)
def test_the_two_dreamerv3_score_sets_differ_as_docs_say(name, scores):
    """docs/dreamerv3.md: the mean of the training episodes past 950k frames, in each set."""
    if not installed(name):
        pytest.skip(f"the data of {name} is not installed")
    curves = load_reference(name)
    late = curves[curves["x"] > 950_000].groupby("task")["return"].mean()
    assert {task: round(late[task]) for task in scores} == pytest.approx(scores, abs=1)


@pytest.mark.skipif(installed("dreamerv3-2023"), reason="the 2023 scores are installed")
def test_a_reference_without_its_data_file_names_the_file_to_add(tmp_path):
    with pytest.raises(
        FileNotFoundError,
        match=r"save danijar/dreamerv3 scores/data/dmcvision_dreamerv3.json.gz at "
        r"commit 8fa35f8 as it is to sb3_ef/analysis/reference_data/dmcvision_dreamerv3_2023.json.gz",
    ):
        check_reference_data("dreamerv3-2023")
    runs = tmp_path / "runs"
    runs.mkdir()
    _records("mine", "dmc/walker-walk-v0", {0: [0.0, 1.0]}).to_csv(runs / "records.csv", index=False)
    with pytest.raises(FileNotFoundError, match="needs its data file"):
        analyze_results(str(runs), str(tmp_path / "out"), reference="dreamerv3-2023")
    assert not (tmp_path / "out").exists()


def test_the_authors_scores_files_are_read_as_they_are(tmp_path):
    runs = [
        {"task": "dmc_walker_walk", "method": "dreamerv3", "seed": "0", "xs": [1000, 2000], "ys": [10.123, 20.0]},
        {"task": "dmc_ball_in_cup_catch", "method": "dreamerv3", "seed": 1, "xs": [1000], "ys": [5.0]},
        {"task": "dmc_walker_walk", "method": "curl", "seed": 0, "xs": [1000], "ys": [1.0]},
    ]
    with gzip.open(tmp_path / "scores.json.gz", "wt") as file:
        json.dump(runs, file)
    table = authors_scores(tmp_path / "scores.json.gz")
    assert table.values.tolist() == [
        ["walker-walk", 0, 1000, 10.12], ["walker-walk", 0, 2000, 20.0], ["ball-in-cup-catch", 1, 1000, 5.0]
    ]  # fmt: skip
    with pytest.raises(ValueError, match="holds no runs of the method 'dreamer'"):
        authors_scores(tmp_path / "scores.json.gz", method="dreamer")


def test_dreamerv3_and_curl_are_on_the_frame_axis():
    # Dreamer-v3's logger counts frames: within a burst of episodes the points are one agent step (2 frames) apart.
    dreamer = load_reference("dreamerv3")
    seed = dreamer[(dreamer["task"] == "walker-walk") & (dreamer["seed"] == 0)].sort_values("x")
    assert seed["x"].iloc[:3].tolist() == [8002, 8004, 8006] and seed["x"].max() < 1_000_000
    curl = load_reference("curl")
    assert sorted(set(np.diff(curl[(curl["task"] == "walker-walk") & (curl["seed"] == 0)]["x"]))) == [20_000]
    for name in ("dreamerv3", "curl"):
        assert get_reference(name).x_column == "frame" and len(set(load_reference(name)["task"])) == 20


def test_ball_in_cup_catch_has_sb3_efs_name_in_every_reference():
    records = _records("mine", "dmc/ball-in-cup-catch-v0", {0: [0.0, 10.0]})
    for name in ("drqv2", "dreamerv3", "dreamerv3-2023", "curl"):
        assert missing_tasks(records, name) == []
        assert reference_table(records, name, at=(20_000,))["official_seeds"].iloc[0] > 0


def test_seed_band_puts_seeds_on_other_grids_on_one_common_grid():
    official = pd.DataFrame({"task": "t", "seed": [0, 0, 0, 1, 1], "x": [0, 10, 20, 5, 15],
                             "return": [0.0, 10.0, 20.0, 20.0, 30.0]})  # fmt: skip
    band = seed_band(official)
    # The union of the points that both seeds span (5 to 15); seed 0 at 5 and 15 and seed 1 at 10, interpolated.
    assert band["x"].tolist() == [5.0, 10.0, 15.0] and band["seeds"].tolist() == [2, 2, 2]
    assert band["mean"].tolist() == [12.5, 17.5, 22.5]
    assert band["min"].tolist() == [5.0, 10.0, 15.0] and band["max"].tolist() == [20.0, 25.0, 30.0]
    assert seed_band(official, end=10)["x"].tolist() == [5.0, 10.0]
    even = seed_band(official, points=5)  # an even grid over the same span
    assert even["x"].tolist() == [5.0, 7.5, 10.0, 12.5, 15.0]
    assert even["mean"].tolist() == [12.5, 15.0, 17.5, 20.0, 22.5]
    assert official_at(official, 12.5).tolist() == [12.5, 27.5]


def test_the_official_dreamerv3_band_has_every_seed_at_every_point():
    # The seeds' training episodes end at different frames: on their union each x holds all of them.
    walker = load_reference("dreamerv3").query("task == 'walker-walk'")
    band = seed_band(walker, end=200_000)
    assert set(band["seeds"]) == {walker["seed"].nunique()} and len(band) > 100
    assert band["x"].iloc[0] == walker.groupby("seed")["x"].min().max()


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


@pytest.mark.parametrize("name", ["dreamerv3", "curl"])
def test_results_command_puts_the_committed_cpu_grid_beside_dreamerv3_and_curl(name, tmp_path, capsys):
    out = tmp_path / "analysis"
    argv = ["results", str(CPU_GRID_RESULTS), "--finished-only", "--at", "20000", "--reference", name]
    assert analyze_main([*argv, "--out", str(out), "--reps", "50"]) == 0
    table = pd.read_csv(out / f"reference_{name}.csv")
    assert len(table) == 4 and set(table["x"]) == {40000} and set(table["unit"]) == {"frame"}
    # The official side, interpolated here from the shipped file at 40k frames (20k agent steps at action repeat 2).
    curves = load_reference(name)
    for task, reference_name in (("dmc/cartpole-balance-v0", "cartpole-balance"),
                                 ("dmc/cartpole-swingup-v0", "cartpole-swingup")):  # fmt: skip
        runs = curves[curves["task"] == reference_name].groupby("seed")
        expected = [np.interp(40000, run["x"], run["return"]) for _, run in runs]
        row = table[(table["algo"] == "DrQv2") & (table["task"] == task)].iloc[0]
        assert row["official_seeds"] == 10 and row["official_mean"] == pytest.approx(np.mean(expected))
    # Known values from the source files (danijar/dreamerv3 scores/), independent of the conversion.
    balance = table[(table["algo"] == "DrQv2") & (table["task"] == "dmc/cartpole-balance-v0")].iloc[0]
    assert balance["official_mean"] == pytest.approx({"dreamerv3": 579.3, "curl": 809.5}[name], abs=0.1)
    printed = capsys.readouterr().out
    assert f"Against {get_reference(name).label}" in printed and "x in frames (agent steps x action repeat" in printed
    assert "Warning" not in printed  # episode returns, 2 frames per step: nothing to doubt
    assert len(list(out.glob(f"reference_{name}_*.png"))) == 2


def test_units_that_look_wrong_are_warned_about(tmp_path, capsys):
    # Success rates in [0, 1], with frame = step: neither DMC returns nor action repeat 2.
    records = _records("mine", "dmc/walker-walk-v0", {0: [0.0, 0.5, 1.0], 1: [0.1, 0.2, 0.3]}, action_repeat=1)
    warnings = unit_warnings(records, "drqv2")
    assert len(warnings) == 2
    assert "every return lies in [0, 1]" in warnings[0] and "success rates" in warnings[0]
    assert "action repeat 1" in warnings[1] and "action repeat 2" in warnings[1] and "frame column" in warnings[1]
    assert unit_warnings(_records("mine", "dmc/walker-walk-v0", {0: [0.0, 350.0]}), "tdmpc2") == []
    # Tasks the reference lacks are not judged.
    assert unit_warnings(_records("mine", "metaworld/hammer-v3", {0: [0.0, 1.0]}, action_repeat=1), "drqv2") == []
    runs = tmp_path / "runs"
    runs.mkdir()
    records.to_csv(runs / "records.csv", index=False)
    assert analyze_main(["results", str(runs), "--out", str(tmp_path / "out"), "--reps", "10", "--reference",
                         "dreamerv3"]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert (
        printed.count("Warning: ") == 2
        and "Dreamer-v3 (official, 2024 release, model 12M) holds DMC episode returns" in printed
    )


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
