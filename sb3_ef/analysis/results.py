"""``sb3-ef analyze results``: every table and plot of a results folder, computed in full before any is written."""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from sb3_ef.analysis._optional import pyplot
from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.common.files import write_text_atomically

if TYPE_CHECKING:
    import pandas as pd


def check_results_arguments(
    directory: str, out: str, return_scale: float, reps: int, at: tuple[int, ...], reference: str | None
) -> None:
    """Raise a ``ValueError`` / ``FileNotFoundError`` naming the first argument that cannot work."""
    from sb3_ef.analysis.reference import check_reference_data

    if not os.path.isdir(directory):
        what = "is a file, not a folder" if os.path.exists(directory) else "does not exist"
        raise FileNotFoundError(f"The results folder {directory!r} {what}: pass the folder holding the evaluation CSVs")
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValueError(f"The output folder {out!r} is a file: pass a folder (--out)")
    if isinstance(reps, bool) or not isinstance(reps, int) or reps < 1:
        raise ValueError(f"reps (--reps) must be a positive number of bootstrap resamples, got {reps!r}")
    if not return_scale > 0:
        raise ValueError(f"return_scale (--return-scale) must be positive, got {return_scale!r}")
    if any(step < 0 for step in at):
        raise ValueError(f"Steps (--at) must be non-negative agent steps, got {list(at)}")
    if reference is not None:
        check_reference_data(reference)  # an unknown name first


@dataclass
class ResultTables:
    """What ``analyze results`` writes, computed first: tables by file name and the lines to print."""

    scores: pd.DataFrame
    tables: dict[str, tuple[pd.DataFrame, bool]] = field(default_factory=dict)  # name -> (table, with index)
    ens: pd.Series | None = None
    rliable: pd.DataFrame | None = None
    lines: list[str] = field(default_factory=list)
    unit_warnings: list[str] = field(default_factory=list)


def _aggregate(records: pd.DataFrame, return_scale: float, reps: int, at: tuple[int, ...]) -> ResultTables:
    """Scores, ENS and rliable metrics (over the tasks every algorithm has) and ``returns_at``."""
    from sb3_ef.analysis.metrics import records_to_scores

    left_out = _check_steps_reached(records, at)  # before the bootstrap
    scores = records_to_scores(records, return_scale=return_scale)
    result = ResultTables(scores, {"scores.csv": (scores, False)})
    _compare(records, return_scale, reps, result)
    if at:
        _returns_at(records, at, result)
        result.lines += left_out
    return result


def _compare(records: pd.DataFrame, return_scale: float, reps: int, result: ResultTables) -> None:
    """ENS and rliable metrics over the tasks every algorithm has (rliable with even seed counts there)."""
    from sb3_ef.analysis.metrics import (
        ENS_THRESHOLDS,
        efficiency_normalized_score,
        ens_table,
        rliable_metrics,
        tasks_with_every_algorithm,
        uneven_seed_counts,
    )

    scores = result.scores
    shared = tasks_with_every_algorithm(scores)
    compared = scores[scores["task"].isin(shared)]
    left_out = sorted(set(scores["task"]) - set(shared))
    if left_out and shared:
        result.lines.append(
            f"ENS and rliable over {shared} only; left out, without results of every algorithm: {left_out}"
        )
    if scores["algo"].nunique() < 2:
        result.lines.append("ENS compares algorithms: skipped with a single algorithm")
    elif not shared:
        tasks = {str(algo): sorted(map(str, group.unique())) for algo, group in scores.groupby("algo")["task"]}
        result.lines.append(
            "ENS and rliable skipped: they compare algorithms on the same tasks, and no task has results of every "
            f"algorithm; tasks per algorithm: {tasks}"
        )
        return
    else:
        result.tables["ens_details.csv"] = (ens_table(compared), False)
        result.ens = efficiency_normalized_score(compared)
        result.tables["ens.csv"] = (result.ens, True)
        thresholds = "/".join(f"{100 * threshold:g}%" for threshold in ENS_THRESHOLDS)
        result.lines.append(
            "ENS (Efficiency Normalised Score, 0 to 1; each algorithm's score where the best curve first reaches "
            f"{thresholds} of the best score, over the best score, averaged over thresholds and tasks):"
        )
        table = result.ens.rename("ENS").rename_axis("algo").reset_index()
        result.lines.append(table.to_string(index=False, float_format="%.3f"))
    uneven = uneven_seed_counts(compared)
    if uneven:
        result.lines.append(f"rliable metrics skipped: they need as many seeds on every task, seeds per task: {uneven}")
        return
    result.rliable = rliable_metrics(compared, reps=reps)
    result.tables["rliable.csv"] = (result.rliable, False)
    result.lines.append(
        f"rliable aggregates of each run's best score ({_score_scale(records, return_scale)}), with 95% "
        f"stratified-bootstrap confidence intervals over {reps} resamples:"
    )
    result.lines.append(result.rliable.to_string(index=False, float_format="%.3f"))


def _check_steps_reached(records: pd.DataFrame, at: tuple[int, ...]) -> list[str]:
    """Refuse steps past every run's last step; the lines naming the runs that end before a step of ``at``."""
    last = records.groupby(["algo", "task", "seed"], dropna=False)["step"].max()
    latest = int(last.max())
    past = [step for step in at if step > latest]
    if past:
        raise ValueError(
            f"Steps (--at) {past} lie past the last step of every run (the longest run ends at step {latest}): "
            f"pick a step <= {latest}"
        )
    lines = []
    for step in at:
        short = last[last < step]
        if not short.empty:
            runs = [f"{algo} on {task} seed {seed} (last step {end})" for (algo, task, seed), end in short.items()]
            lines.append(f"Left out at step {step} (--at), ended before it: {', '.join(runs)}")
    return lines


def _returns_at(records: pd.DataFrame, at: tuple[int, ...], result: ResultTables) -> None:
    """The ``returns_at`` table at the ``--at`` steps, and the steps no run was evaluated at."""
    from sb3_ef.analysis.metrics import returns_at

    at_steps = returns_at(records, at)
    result.tables["returns_at.csv"] = (at_steps, False)
    result.lines.append("Evaluation return at the --at agent steps (episode returns, not scaled), over seeds:")
    result.lines.append(at_steps.to_string(index=False, float_format="%.1f"))
    unevaluated = sorted(set(at) - set(at_steps["step"]))
    if unevaluated:
        result.lines.append(f"No run was evaluated at step(s) {unevaluated} exactly: returns_at.csv has no row there")


def _skipped_csvs(directory: str) -> list[str]:
    """The CSVs under ``directory`` with a ``return`` column but not the record header (skipped by the reader)."""
    skipped = []
    for path in sorted(glob.glob(os.path.join(directory, "**", "*.csv"), recursive=True)):
        with open(path, errors="replace") as file:
            header = file.readline().strip().split(",")
        if "return" in header and tuple(header) != RECORD_COLUMNS:
            missing = [column for column in RECORD_COLUMNS if column not in header]
            skipped.append(f"{path} (columns {header}, missing {missing})")
    return skipped


def _score_scale(records: pd.DataFrame, return_scale: float) -> str:
    """How scores come from the records, in words."""
    with_success = records.groupby("task")["success"].agg(lambda column: column.notna().all())
    parts = []
    if not with_success.all():
        parts.append(f"score = episode return / {return_scale:g} (--return-scale)")
    if with_success.any():
        parts.append("score = success rate on the tasks that record one")
    return "; ".join(parts)


def _against_reference(records: pd.DataFrame, name: str, at: tuple[int, ...], result: ResultTables) -> None:
    """Add the table of your runs beside a published reference, with its unit warnings."""
    from sb3_ef.analysis.reference import get_reference, missing_tasks, reference_table, unit_warnings

    reference = get_reference(name)
    missing = missing_tasks(records, name)
    if missing:
        result.lines.append(f"No {reference.label} curves for {missing}: left out of the comparison")
    result.unit_warnings = unit_warnings(records, name)
    result.lines += [f"Warning: {warning}" for warning in result.unit_warnings]
    table = reference_table(records, name, at)
    result.tables[f"reference_{name}.csv"] = (table, False)
    result.lines.append(
        f"Against {reference.label}: {reference.source}; x in {reference.unit}; mean, std, min and max are episode "
        "returns (not scaled), yours over your seeds, official_* over the official seeds at the same x:"
    )
    shown = table.drop(columns="reference")
    result.lines.append(shown.to_string(index=False, float_format="%.1f") if not table.empty else "no task in common")


def analyze_results(
    directory: str,
    out: str,
    return_scale: float = 1000.0,
    reps: int = 2000,
    at: tuple[int, ...] = (),
    finished_only: bool = False,
    reference: str | None = None,
) -> dict[str, Any]:
    """Compute every table of ``directory``, then write them and the plots to ``out`` (bad input writes nothing)."""
    from sb3_ef.analysis.metrics import load_records
    from sb3_ef.analysis.plots import plot_ens, plot_intervals, plot_learning_curves, plot_reference_curves

    at = tuple(at)
    check_results_arguments(directory, out, return_scale, reps, at, reference)
    pyplot()  # matplotlib missing: reported before anything is written
    skipped = _skipped_csvs(directory)
    try:
        records = load_records(directory, finished_only)
    except FileNotFoundError as error:
        if not skipped:
            raise
        raise ValueError(f"{error}; skipped, without that header: {'; '.join(skipped)}") from error
    result = _aggregate(records, return_scale, reps, at)
    header = ",".join(RECORD_COLUMNS)
    result.lines[:0] = [f"Warning: skipped {csv}: evaluation records need the header {header}" for csv in skipped]
    if reference is not None:
        _against_reference(records, reference, at, result)
    os.makedirs(out, exist_ok=True)
    for name, (table, index) in result.tables.items():
        write_text_atomically(os.path.join(out, name), table.to_csv(index=index))
    written: dict[str, Any] = {"curves": plot_learning_curves(result.scores, out)}
    if result.ens is not None:
        written["ens"] = plot_ens(result.ens, os.path.join(out, "ens.png"))
    if result.rliable is not None:
        written["rliable"] = plot_intervals(result.rliable, os.path.join(out, "rliable.png"))
    if reference is not None:
        written["reference_table"] = os.path.join(out, f"reference_{reference}.csv")
        written["reference_curves"] = plot_reference_curves(records, reference, out)
        written["unit_warnings"] = result.unit_warnings
    scores = result.scores
    print(f"Scores of {scores['algo'].nunique()} algorithm(s) on {scores['task'].nunique()} task(s) -> {out}")
    print("\n".join(result.lines))
    return written
