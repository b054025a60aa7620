"""Figures written to files (matplotlib, Agg): learning curves, ENS bars, rliable plots, predictions, saliency."""

from __future__ import annotations

import os
import re
from typing import TYPE_CHECKING

import numpy as np

from sb3_ef.analysis._optional import pyplot
from sb3_ef.analysis.metrics import SCORE_COLUMNS, check_columns
from sb3_ef.analysis.records import RECORD_COLUMNS
from sb3_ef.common.files import atomic_path

if TYPE_CHECKING:
    import pandas as pd

    from sb3_ef.analysis.report import ForesightReport


#: Points of the even grid the official curves are drawn on.
REFERENCE_POINTS = 200


def _safe_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name)


def _save(figure, path: str | os.PathLike) -> str:
    """Write ``figure`` to ``path`` whole or not at all (its format from the suffix), and close it."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    figure.tight_layout()
    try:
        with atomic_path(path) as temporary:
            figure.savefig(temporary, dpi=100)
    finally:
        pyplot().close(figure)
    return os.fspath(path)


def plot_learning_curves(scores: pd.DataFrame, out_dir: str | os.PathLike, xlabel: str = "step") -> list[str]:
    """``<out_dir>/curve_<task>.png``: each algorithm's mean score over seeds with a 95% band; the paths."""
    from sb3_ef.analysis.reference import seed_band

    check_columns(scores, SCORE_COLUMNS)
    plt = pyplot()
    paths = []
    for task, task_scores in scores.groupby("task"):
        figure, axis = plt.subplots(figsize=(5, 3.5))
        for algo, group in task_scores.groupby("algo"):
            band = seed_band(group, x="step", y="score")
            axis.plot(band["x"], band["mean"], label=f"{algo} ({group['seed'].nunique()} seeds)")
            half_width = 1.96 * band["std"].fillna(0.0) / np.sqrt(band["seeds"])
            axis.fill_between(band["x"], band["mean"] - half_width, band["mean"] + half_width, alpha=0.25)
        axis.set(title=str(task), xlabel=xlabel, ylabel="score")
        axis.legend()
        paths.append(_save(figure, os.path.join(os.fspath(out_dir), f"curve_{_safe_name(str(task))}.png")))
    return paths


def plot_reference_curves(records: pd.DataFrame, name: str, out_dir: str | os.PathLike) -> list[str]:
    """``<out_dir>/reference_<name>_<task>.png``: your mean and min-max returns beside the official ones; the paths."""
    from sb3_ef.analysis.reference import get_reference, load_reference, reference_task, seed_band

    check_columns(records, RECORD_COLUMNS)
    plt, reference, official, paths = pyplot(), get_reference(name), load_reference(name), []
    for task, group in records.groupby("task"):
        curves = official[official["task"] == reference_task(str(task))]
        if curves.empty:
            continue
        figure, axis = plt.subplots(figsize=(5, 3.5))
        for algo, runs in group.groupby("algo"):
            yours = seed_band(runs, x=reference.x_column)
            axis.plot(yours["x"], yours["mean"], label=f"{algo} ({runs['seed'].nunique()} seeds)")
            axis.fill_between(yours["x"], yours["min"], yours["max"], alpha=0.2)
        band = seed_band(curves, end=1.1 * float(group[reference.x_column].max()), points=REFERENCE_POINTS)
        label = f"{reference.label} ({curves['seed'].nunique()} seeds)"
        axis.plot(band["x"], band["mean"], color="black", linestyle="--", label=label)
        axis.fill_between(band["x"], band["min"], band["max"], color="black", alpha=0.1)
        axis.set(title=str(task), xlabel=reference.axis, ylabel="episode return")
        axis.legend(fontsize="small")
        paths.append(_save(figure, os.path.join(os.fspath(out_dir), f"reference_{name}_{_safe_name(str(task))}.png")))
    return paths


def plot_ens(ens: pd.Series, path: str | os.PathLike) -> str:
    """Bar chart of the Efficiency Normalised Score per algorithm."""
    plt = pyplot()
    figure, axis = plt.subplots(figsize=(max(3.0, 1.2 * len(ens)), 3.5))
    axis.bar([str(algo) for algo in ens.index], ens.to_numpy())
    axis.set(ylim=(0, 1), ylabel="ENS", title="Efficiency Normalised Score")
    return _save(figure, path)


def plot_intervals(table: pd.DataFrame, path: str | os.PathLike) -> str:
    """One panel per rliable metric: per algorithm, a bar over the CI and a tick at the estimate."""
    check_columns(table, ("algo", "metric", "estimate", "lower", "upper"))
    plt = pyplot()
    metrics, algos = list(dict.fromkeys(table["metric"])), list(dict.fromkeys(table["algo"]))
    figure, axes = plt.subplots(1, len(metrics), figsize=(3 * len(metrics), 0.6 * len(algos) + 1.2), squeeze=False)
    for axis, metric in zip(axes[0], metrics, strict=True):
        rows = table[table["metric"] == metric].set_index("algo").reindex(algos)
        positions = np.arange(len(algos))
        axis.barh(positions, rows["upper"] - rows["lower"], left=rows["lower"], height=0.6, alpha=0.5)
        axis.vlines(rows["estimate"], positions - 0.3, positions + 0.3, color="black")
        axis.set_yticks(positions, algos if axis is axes[0][0] else [""] * len(algos))
        axis.set(title=metric, xlabel="normalised score")
    return _save(figure, path)


def _frame_row_axes(axis, rows: list[str], columns: list[str], frame_size: int, spacing: int = 2) -> None:
    """Label the rows and columns of a :func:`~sb3_ef.analysis.prediction.frame_grid` image."""
    cell = frame_size + spacing
    axis.set_yticks([cell * (index + 0.5) for index in range(len(rows))], rows)
    axis.set_xticks([cell * (index + 0.5) for index in range(len(columns))], columns)


def plot_prediction(report: ForesightReport, path: str | os.PathLike, title: str) -> str:
    """The context, predicted and true frames of ``report`` as one labelled figure: rows named, columns ``t+k``."""
    return _save(prediction_figure(report, title), path)


def prediction_figure(report: ForesightReport, title: str):
    """The figure of :func:`plot_prediction` (open, for display or inspection)."""
    image = report.prediction_image()
    contexts = report.rollout.first_observation.shape[0] // report.predicted.shape[-1]
    steps = max(len(report.predicted), contexts)
    figure, axis = pyplot().subplots(figsize=(max(4.0, 1.1 * (steps + 1)), 3.8))
    axis.imshow(image)
    columns = [f"t+{index + 1}" for index in range(len(report.predicted))]
    frame_size = report.predicted.shape[1]
    _frame_row_axes(axis, ["context", "predicted", "true"], columns, frame_size)
    axis.set_xlabel("predicted and true frames")
    # The context row's columns (the stacked frames up to t) get their own labels, above the grid.
    context = axis.secondary_xaxis("top")
    context.set_xticks(
        [(frame_size + 2) * (index + 0.5) for index in range(contexts)],
        [f"t-{contexts - 1 - index}" if index < contexts - 1 else "t" for index in range(contexts)],
    )
    context.set_xlabel("context frames")
    axis.set_title(title, pad=30)
    return figure


def plot_saliency(report: ForesightReport, path: str | os.PathLike, title: str) -> str:
    """The last predicted frame and its saliency maps, each panel titled (h_a in red, h_s in blue)."""
    return _save(saliency_figure(report, title), path)


def saliency_figure(report: ForesightReport, title: str):
    """The figure of :func:`plot_saliency` (open, for display or inspection)."""
    panels = report.saliency_panels()
    if report.rollout.agent_mask is not None:
        panels["true agent mask"] = report.rollout.agent_mask
    figure, axes = pyplot().subplots(1, len(panels), figsize=(2.4 * len(panels), 2.9))
    for axis, (name, image) in zip(axes, panels.items(), strict=True):
        axis.imshow(image, cmap="gray" if image.ndim == 2 else None)
        axis.set_title(name, fontsize=9)
        axis.axis("off")
    figure.suptitle(title)
    return figure
