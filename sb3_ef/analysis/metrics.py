"""Aggregate scores over algorithms, tasks and seeds: the Efficiency Normalised Score (docs/analysis.md), rliable."""

from __future__ import annotations

import glob
import os
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from sb3_ef.analysis._optional import require
from sb3_ef.analysis.records import RECORD_COLUMNS, RUN_RESULT_FILE

if TYPE_CHECKING:
    import pandas as pd

SCORE_COLUMNS = ("algo", "task", "seed", "step", "score")
ENS_THRESHOLDS = (0.95, 0.90, 0.85)
RLIABLE_METRICS = ("Median", "IQM", "Mean", "Optimality Gap")


def check_columns(df: pd.DataFrame, columns: tuple[str, ...]) -> None:
    """Raise a ValueError naming the missing columns, or if the table is empty."""
    missing = [column for column in columns if column not in df.columns]
    if missing:
        raise ValueError(f"Expected columns {columns}, missing {missing} (got {tuple(df.columns)})")
    if df.empty:
        raise ValueError("Expected at least one row of scores, got an empty table")


def load_records(directory: str | os.PathLike, finished_only: bool = False) -> pd.DataFrame:
    """Every evaluation CSV and rl-zoo3 ``evaluations.npz`` under ``directory``, checked (optionally finished only)."""
    from sb3_ef.analysis.zoo_logs import EVALUATIONS_FILE, is_zoo_run_folder, zoo_run_finished, zoo_run_records

    pandas = require("pandas")
    root = os.fspath(directory)
    frames, record_folders, without_rows = [], set(), []
    for path in sorted(glob.glob(os.path.join(root, "**", "*.csv"), recursive=True)):
        with open(path, errors="replace") as file:
            header = tuple(file.readline().strip().split(","))
        if header != RECORD_COLUMNS:
            continue
        record_folders.add(os.path.dirname(os.path.abspath(path)))
        if finished_only and not os.path.isfile(os.path.join(path[: -len(".csv")], RUN_RESULT_FILE)):
            continue
        table = pandas.read_csv(path, dtype=str, keep_default_na=False)
        if table.empty:  # a header alone: a run without an evaluation yet
            without_rows.append(path)
        else:
            frames.append(check_record_values(table, path))
    for path in sorted(glob.glob(os.path.join(root, "**", EVALUATIONS_FILE), recursive=True)):
        run_folder = os.path.dirname(os.path.abspath(path))
        if not is_zoo_run_folder(run_folder) or os.path.isfile(run_folder + ".csv"):
            continue  # not laid out by rl-zoo3, or a benchmark run (<run>.csv beside <run>/)
        if any(folder == run_folder or folder.startswith(run_folder + os.sep) for folder in record_folders):
            continue  # the run's own evaluation CSV is read instead
        if finished_only and not zoo_run_finished(run_folder):
            continue
        frames.append(check_record_values(zoo_run_records(run_folder), path))
    if not frames and without_rows:
        raise ValueError(f"The evaluation CSVs under {directory} hold no evaluation yet: {without_rows}")
    if not frames:
        which = f" of a finished run ({RUN_RESULT_FILE} beside it)" if finished_only else ""
        raise FileNotFoundError(
            f"No evaluation CSV{which} with header {','.join(RECORD_COLUMNS)}, nor an rl-zoo3 run folder with "
            f"{EVALUATIONS_FILE}, under {directory}"
        )
    return pandas.concat(frames, ignore_index=True)


def _bad_values(table: pd.DataFrame, column: str, valid: Callable[[pd.Series], pd.Series]) -> pd.Series:
    """Rows of ``table`` whose ``column`` is not a number meeting ``valid`` (empty counts as not a number)."""
    pandas = require("pandas")
    numbers = pandas.to_numeric(table[column], errors="coerce")
    return ~(numbers.notna() & valid(numbers))


#: Per numeric column of the records: what a value must be, and the test.
RECORD_VALUE_RULES: dict[str, tuple[str, Callable[[pd.Series], pd.Series]]] = {
    "step": ("a whole number of agent steps >= 0", lambda values: (values >= 0) & (values % 1 == 0)),
    "frame": ("a whole number of frames >= 0", lambda values: (values >= 0) & (values % 1 == 0)),
    "return": ("a finite number (the mean episode return)", lambda values: np.isfinite(values)),
}


def check_record_values(records: pd.DataFrame, source: str | os.PathLike) -> pd.DataFrame:
    """``records`` with numeric columns, or a ``ValueError`` naming the line and value of each bad column."""
    pandas = require("pandas")
    check_columns(records, RECORD_COLUMNS)
    problems = []

    def describe(column: str, bad: pd.Series, expected: str) -> None:
        if bad.any():
            first = int(np.flatnonzero(bad.to_numpy())[0])
            count = f" (and {int(bad.sum()) - 1} more)" if bad.sum() > 1 else ""
            problems.append(f"line {first + 2}: {column} {records[column].iloc[first]!r}, expected {expected}{count}")

    for column in ("algo", "task"):
        describe(column, records[column].isna() | (records[column].astype(str).str.strip() == ""), "a name")
    for column, (expected, valid) in RECORD_VALUE_RULES.items():
        describe(column, _bad_values(records, column, valid), expected)
    filled = records["success"].notna() & ~records["success"].astype(str).str.strip().isin(["", "nan", "NaN"])
    describe("success", filled & _bad_values(records, "success", lambda values: values.between(0, 1)),
             "empty or a success rate in [0, 1]")  # fmt: skip
    if problems:
        raise ValueError(f"{source} holds values that are not evaluation records: " + "; ".join(problems))
    checked = records.copy()
    for column in ("step", "frame"):
        checked[column] = pandas.to_numeric(checked[column]).astype(int)
    checked["return"] = pandas.to_numeric(checked["return"]).astype(float)
    checked["success"] = pandas.to_numeric(checked["success"].where(filled), errors="coerce").astype(float)
    checked["seed"] = _seed_column(checked["seed"])
    return checked


def _seed_column(seeds: pd.Series) -> pd.Series:
    """Seeds as whole numbers where every given one is (an empty one: NaN), else as names."""
    pandas = require("pandas")
    names = seeds.astype(str).str.strip()
    given = names != ""
    numbers = pandas.to_numeric(names.where(given), errors="coerce")
    if not (numbers.notna() == given).all() or not (numbers.dropna() % 1 == 0).all():
        return names.where(given)
    return numbers.astype(int) if given.all() else numbers


def records_to_scores(records: pd.DataFrame, return_scale: float = 1000.0) -> pd.DataFrame:
    """Scores: per task, the success rate where every record has one, else ``return / return_scale``."""
    check_columns(records, RECORD_COLUMNS)
    if return_scale <= 0:
        raise ValueError(f"return_scale must be positive, got {return_scale}")
    has_success = records.groupby("task")["success"].transform(lambda column: column.notna().all())
    scores = records[["algo", "task", "seed", "step"]].copy()
    scores["score"] = np.where(has_success, records["success"], records["return"] / return_scale).astype(float)
    return scores


def performance_curves(scores: pd.DataFrame) -> pd.DataFrame:
    """Mean score over seeds per ``(algo, task, step)``, sorted by step."""
    check_columns(scores, SCORE_COLUMNS)
    return (
        scores.groupby(["algo", "task", "step"], as_index=False)["score"].mean().sort_values(["algo", "task", "step"])
    )


def returns_at(records: pd.DataFrame, steps: tuple[int, ...]) -> pd.DataFrame:
    """Evaluation return at ``steps`` over seeds: ``mean``, ``std``, ``seeds`` and the ``returns`` themselves."""
    check_columns(records, RECORD_COLUMNS)
    if not steps or any(step < 0 for step in steps):
        raise ValueError(f"Expected one or more non-negative steps, got {steps}")
    chosen = records[records["step"].isin(steps)].sort_values(["algo", "task", "step", "seed"])
    grouped = chosen.groupby(["algo", "task", "step"])["return"]
    table = grouped.agg(["mean", "std", "count"]).rename(columns={"count": "seeds"})
    table["returns"] = grouped.agg(lambda column: [round(float(value), 1) for value in column])
    return table.reset_index()


def ens_table(scores: pd.DataFrame, thresholds: tuple[float, ...] = ENS_THRESHOLDS) -> pd.DataFrame:
    """Per task and threshold, the threshold step and each algorithm's normalised score there."""
    pandas = require("pandas")
    curves = performance_curves(scores)
    algos = sorted(curves["algo"].unique())
    rows = []
    for task, task_curves in curves.groupby("task"):
        present = set(task_curves["algo"])
        if present != set(algos):
            raise ValueError(f"Task {task!r} has results for {sorted(present)}, expected every algorithm {algos}")
        by_algo = {
            algo: (group["step"].to_numpy(float), group["score"].to_numpy(float))
            for algo, group in task_curves.groupby("algo")
        }
        maximum = task_curves["score"].max()
        if maximum <= 0:
            raise ValueError(f"Task {task!r}: the best performance is {maximum}, ENS needs a positive maximum")
        grid = np.unique(task_curves["step"].to_numpy(float))
        values = np.stack([np.interp(grid, steps, curve) for steps, curve in by_algo.values()])
        best = values.max(axis=0)
        for threshold in thresholds:
            if not 0 < threshold <= 1:
                raise ValueError(f"ENS thresholds must be in (0, 1], got {threshold}")
            # relative tolerance so that e.g. 0.95 * M reached exactly is not lost to rounding
            index = int(np.argmax(best >= threshold * maximum * (1 - 1e-12)))
            rows += [
                {"task": task, "threshold": threshold, "step": grid[index], "algo": algo, "normalized_score": value}
                for algo, value in zip(by_algo, values[:, index] / maximum, strict=True)
            ]
    return pandas.DataFrame(rows)


def efficiency_normalized_score(scores: pd.DataFrame, thresholds: tuple[float, ...] = ENS_THRESHOLDS) -> pd.Series:
    """ENS per algorithm (a Series named ``ens`` indexed by ``algo``), as docs/analysis.md defines it."""
    return ens_table(scores, thresholds).groupby("algo")["normalized_score"].mean().rename("ens")


def tasks_with_every_algorithm(scores: pd.DataFrame) -> list[str]:
    """The tasks (sorted) on which every algorithm of ``scores`` has results: the tasks ENS can compare."""
    check_columns(scores, SCORE_COLUMNS)
    algos = set(scores["algo"])
    present = scores.groupby("task")["algo"].agg(set)
    return sorted(str(task) for task, found in present.items() if found == algos)


def uneven_seed_counts(scores: pd.DataFrame) -> dict[str, dict[str, int]]:
    """Seeds per task of each algorithm whose count differs between tasks (rliable needs them even), or ``{}``."""
    check_columns(scores, SCORE_COLUMNS)
    tasks = sorted(scores["task"].unique())
    counts = scores.groupby(["algo", "task"])["seed"].nunique()
    uneven = {}
    for algo in sorted(scores["algo"].unique()):
        per_task = counts[algo].reindex(tasks, fill_value=0)
        if per_task.nunique() != 1:
            uneven[str(algo)] = {str(task): int(count) for task, count in per_task.items()}
    return uneven


def best_scores(scores: pd.DataFrame) -> dict[str, np.ndarray]:
    """Each run's best score as rliable wants it: ``{algo: (runs, tasks) array}``, tasks and seeds sorted."""
    check_columns(scores, SCORE_COLUMNS)
    best = scores.groupby(["algo", "task", "seed"], as_index=False)["score"].max()
    tasks = sorted(best["task"].unique())
    matrices = {}
    for algo, group in best.groupby("algo"):
        counts = group.groupby("task")["seed"].nunique().reindex(tasks, fill_value=0)
        if counts.nunique() != 1:
            raise ValueError(f"{algo}: rliable needs the same number of seeds on every task, got {counts.to_dict()}")
        columns = [group[group["task"] == task].sort_values("seed")["score"].to_numpy(float) for task in tasks]
        matrices[str(algo)] = np.stack(columns, axis=1)
    return matrices


def stratified_bootstrap(
    matrix: np.ndarray,
    aggregate: Callable[[np.ndarray], np.ndarray],
    reps: int = 2000,
    confidence: float = 0.95,
    rng: np.random.Generator | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Percentile CIs of ``aggregate`` over a (runs, tasks) matrix, runs resampled within each task."""
    rng = np.random.default_rng() if rng is None else rng
    runs, tasks = matrix.shape
    samples = matrix[rng.integers(0, runs, size=(reps, runs, tasks)), np.arange(tasks)]
    statistics = np.stack([aggregate(sample) for sample in samples])
    tail = 100 * (1 - confidence) / 2
    lower, upper = np.percentile(statistics, [tail, 100 - tail], axis=0)
    return lower, upper


def rliable_metrics(scores: pd.DataFrame, reps: int = 2000, seed: int = 0) -> pd.DataFrame:
    """rliable's four aggregates of each run's best score, with stratified-bootstrap CIs (rliable's needs ``arch``)."""
    pandas = require("pandas")
    metrics = require("rliable.metrics")
    names = ("median", "iqm", "mean", "optimality_gap")
    functions = [getattr(metrics, f"aggregate_{name}") for name in names]

    def aggregate(matrix: np.ndarray) -> np.ndarray:
        return np.array([function(matrix) for function in functions])

    rng = np.random.default_rng(seed)
    rows = []
    for algo, matrix in best_scores(scores).items():
        estimate = aggregate(matrix)
        lower, upper = stratified_bootstrap(matrix, aggregate, reps=reps, rng=rng)
        rows += [
            {"algo": algo, "metric": metric, "estimate": estimate[i], "lower": lower[i], "upper": upper[i]}
            for i, metric in enumerate(RLIABLE_METRICS)
        ]
    return pandas.DataFrame(rows)
