"""Aggregate scores over algorithms, tasks and seeds: the Efficiency Normalised Score and rliable metrics.

Definitions (see docs/analysis.md for the worked reasoning):

- Score table: columns ``algo, task, seed, step, score``; ``step`` is the x-axis (agent steps or frames, the same
  unit for every algorithm).
- Performance curve of an algorithm on a task: the mean score over its seeds at each of its evaluation steps.
  Between its evaluation steps the curve is linearly interpolated; before its first / after its last evaluation
  it holds the first / last value.
- M(task): the maximum of all algorithms' performance curves on that task (must be > 0).
- Threshold step for q in (0.95, 0.90, 0.85): the first step, on the union of all algorithms' evaluation steps
  for that task, at which some algorithm's curve reaches ``q * M``.
- Each algorithm's normalised score there: its curve's value at that step divided by M, in [0, 1] for non-negative
  scores. ENS(algo) = mean of those over thresholds and tasks.
"""

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
    """Concatenate every evaluation CSV (header ``algo, task, seed, step, frame, return, success``) under a
    directory, recursively; other CSV files are skipped.

    :param finished_only: only the CSVs of finished runs, those with a ``<name>/result.json`` beside ``<name>.csv``
        (``sb3-ef benchmark``'s results folder), so a grid part-way through is read without its runs in progress.
    """
    pandas = require("pandas")
    frames = []
    for path in sorted(glob.glob(os.path.join(os.fspath(directory), "**", "*.csv"), recursive=True)):
        if finished_only and not os.path.isfile(os.path.join(path[: -len(".csv")], RUN_RESULT_FILE)):
            continue
        with open(path) as file:
            header = tuple(file.readline().strip().split(","))
        if header == RECORD_COLUMNS:
            frames.append(pandas.read_csv(path, keep_default_na=True))
    if not frames:
        which = f" of a finished run ({RUN_RESULT_FILE} beside it)" if finished_only else ""
        raise FileNotFoundError(f"No evaluation CSV{which} with header {','.join(RECORD_COLUMNS)} under {directory}")
    return pandas.concat(frames, ignore_index=True)


def records_to_scores(records: pd.DataFrame, return_scale: float = 1000.0) -> pd.DataFrame:
    """Score table from evaluation records: per task, the success rate when every record of that task has one
    (Meta-World), otherwise ``return / return_scale`` (DMC returns lie in [0, 1000])."""
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
    """Evaluation return at given steps, over seeds: columns ``algo, task, step, mean, std, seeds, returns``.

    ``std`` is the sample standard deviation (NaN for one seed); ``returns`` lists the seeds' returns in seed order.
    Runs without an evaluation at a step (unfinished ones) are left out of that row, which ``seeds`` shows; a step
    that no run reached has no row.
    """
    check_columns(records, RECORD_COLUMNS)
    if not steps or any(step < 0 for step in steps):
        raise ValueError(f"Expected one or more non-negative steps, got {steps}")
    chosen = records[records["step"].isin(steps)].sort_values(["algo", "task", "step", "seed"])
    grouped = chosen.groupby(["algo", "task", "step"])["return"]
    table = grouped.agg(["mean", "std", "count"]).rename(columns={"count": "seeds"})
    table["returns"] = grouped.agg(lambda column: [round(float(value), 1) for value in column])
    return table.reset_index()


def ens_table(scores: pd.DataFrame, thresholds: tuple[float, ...] = ENS_THRESHOLDS) -> pd.DataFrame:
    """Per task and threshold: the threshold step and each algorithm's normalised score there.

    :return: columns ``task, threshold, step, algo, normalized_score``.
    """
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
            for algo, column in zip(by_algo, values[:, index], strict=True):
                rows.append(
                    {
                        "task": task,
                        "threshold": threshold,
                        "step": grid[index],
                        "algo": algo,
                        "normalized_score": column / maximum,
                    }
                )
    return pandas.DataFrame(rows)


def efficiency_normalized_score(scores: pd.DataFrame, thresholds: tuple[float, ...] = ENS_THRESHOLDS) -> pd.Series:
    """ENS per algorithm (a Series named ``ens`` indexed by ``algo``), as defined in this module's docstring."""
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
    """Best evaluation score of every run as rliable wants it: ``{algo: (runs, tasks) array}``, tasks sorted by
    name and runs by seed. Every algorithm needs the same number of seeds on every task."""
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
    """Percentile confidence intervals of ``aggregate`` over a (runs, tasks) matrix, resampling runs with
    replacement independently within each task (rliable's stratified bootstrap).

    :return: (lower, upper), each of the aggregate's shape.
    """
    rng = np.random.default_rng() if rng is None else rng
    runs, tasks = matrix.shape
    samples = matrix[rng.integers(0, runs, size=(reps, runs, tasks)), np.arange(tasks)]
    statistics = np.stack([aggregate(sample) for sample in samples])
    tail = 100 * (1 - confidence) / 2
    lower, upper = np.percentile(statistics, [tail, 100 - tail], axis=0)
    return lower, upper


def rliable_metrics(scores: pd.DataFrame, reps: int = 2000, seed: int = 0) -> pd.DataFrame:
    """Median, IQM, mean and optimality gap (rliable's aggregate functions) of the best normalised score per run,
    with 95% stratified bootstrap confidence intervals over ``reps`` resamples.

    The bootstrap is :func:`stratified_bootstrap` rather than ``rliable.library.get_interval_estimates``: the
    latter depends on ``arch``, which fails to import with pandas 3 (arch 7.x) or refuses rliable's
    ``random_state`` argument (arch 8.x).

    :return: columns ``algo, metric, estimate, lower, upper``.
    """
    pandas = require("pandas")
    metrics = require("rliable.metrics")

    def aggregate(matrix: np.ndarray) -> np.ndarray:
        return np.array(
            [
                metrics.aggregate_median(matrix),
                metrics.aggregate_iqm(matrix),
                metrics.aggregate_mean(matrix),
                metrics.aggregate_optimality_gap(matrix),
            ]
        )

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
