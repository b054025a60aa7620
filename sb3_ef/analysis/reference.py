"""Published learning curves, shipped with the package, and a user's runs put beside them.

Two references, read from ``reference_data/`` (sources and licences in ``reference_data/SOURCES.md``):

- ``"drqv2"``: DrQ-v2's official DMC curves (facebookresearch/drqv2, ``curves/``; 24 tasks, 8-10 seeds), episode
  return against **frames** (agent steps x action repeat 2);
- ``"tdmpc2"``: TD-MPC2's official DMC pixel results (nicklashansen/tdmpc2, ``results/tdmpc2-pixels/``; 12 tasks,
  3 seeds), episode return against **agent steps** (action repeat 2).

A run's evaluation records hold both ``step`` (agent steps) and ``frame``; each reference is compared on its own
axis (frames from the records' ``frame`` column, not from an assumed action repeat). Official seeds are
interpolated linearly between their evaluations and never extrapolated beyond their last one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np

from sb3_ef.analysis._optional import require
from sb3_ef.analysis.metrics import check_columns
from sb3_ef.analysis.records import RECORD_COLUMNS

if TYPE_CHECKING:
    import pandas as pd

REFERENCE_COLUMNS = ("task", "seed", "x", "return")


@dataclass(frozen=True)
class Reference:
    """A published set of learning curves: its data file, the unit of its x-axis and where it comes from."""

    label: str
    file: str
    x_column: str  # the records' column on the same axis: "frame" or "step"
    unit: str
    source: str


REFERENCES = {
    "drqv2": Reference(
        "DrQ-v2 (official)",
        "drqv2_dmc.csv.gz",
        "frame",
        "frames (official runs at action repeat 2)",
        "facebookresearch/drqv2 curves/ (MIT licence)",
    ),
    "tdmpc2": Reference(
        "TD-MPC2 (official)",
        "tdmpc2_pixels_dmc.csv.gz",
        "step",
        "agent steps (official runs at action repeat 2)",
        "nicklashansen/tdmpc2 results/tdmpc2-pixels/ (MIT licence)",
    ),
}


def get_reference(name: str) -> Reference:
    """The reference called ``name``; a ``ValueError`` lists the known ones."""
    if name not in REFERENCES:
        raise ValueError(f"Unknown reference {name!r}: expected one of {sorted(REFERENCES)}")
    return REFERENCES[name]


def reference_task(task: str) -> str:
    """The references' name of a DMC task: ``dmc/cartpole-balance-v0`` or ``dmc/cartpole_balance`` ->
    ``cartpole-balance``."""
    name = task.split("/", 1)[1] if task.startswith("dmc/") else task
    return re.sub(r"-v\d+$", "", name).replace("_", "-")


def load_reference(name: str) -> pd.DataFrame:
    """The reference's curves: columns ``task, seed, x, return`` (``x`` in the reference's unit)."""
    pandas = require("pandas")
    reference = get_reference(name)
    with resources.as_file(resources.files("sb3_ef.analysis") / "reference_data" / reference.file) as path:
        table = pandas.read_csv(path)
    return table.rename(columns={reference.x_column: "x"})[list(REFERENCE_COLUMNS)]


def _official_at(official: pd.DataFrame, x: float) -> np.ndarray:
    """Each official seed's return at ``x`` (linear between its evaluations); seeds that end before ``x`` are left
    out."""
    values = []
    for _, run in official.groupby("seed"):
        run = run.sort_values("x")
        if run["x"].iloc[0] <= x <= run["x"].iloc[-1]:
            values.append(float(np.interp(x, run["x"], run["return"])))
    return np.asarray(values)


def _frames_per_step(group: pd.DataFrame) -> float:
    """The action repeat of a run's records (their ``frame`` over ``step``)."""
    moved = group[group["step"] > 0]
    return float((moved["frame"] / moved["step"]).median()) if not moved.empty else 1.0


def reference_table(records: pd.DataFrame, name: str, at: tuple[int, ...] = ()) -> pd.DataFrame:
    """Your mean at a step vs the official mean (min-max) at the same point, per algorithm and task of ``records``.

    ``at`` gives agent steps (as ``--at`` does everywhere); by default each algorithm's last step that all its seeds
    reached on that task. The comparison is made on the reference's own axis (``x``, in ``unit``: frames for
    DrQ-v2, read from the records' ``frame`` column, agent steps for TD-MPC2). Tasks the reference lacks are left
    out (see :func:`missing_tasks`).

    :return: columns ``algo, task, step, x, unit, seeds, mean, std, official_seeds, official_mean, official_min,
        official_max``; ``official_*`` are NaN (and ``official_seeds`` 0) where no official seed reached ``x``.
    """
    pandas = require("pandas")
    check_columns(records, RECORD_COLUMNS)
    if any(step < 0 for step in at):
        raise ValueError(f"Expected non-negative steps, got {at}")
    reference = get_reference(name)
    official = load_reference(name)
    rows = []
    for (algo, task), group in records.groupby(["algo", "task"]):
        curves = official[official["task"] == reference_task(str(task))]
        if curves.empty:
            continue
        runs = [run.sort_values("step") for _, run in group.groupby("seed")]
        steps = at or (min(int(run["step"].iloc[-1]) for run in runs),)
        scale = _frames_per_step(group) if reference.x_column == "frame" else 1.0
        for step in steps:
            yours = np.asarray([
                float(np.interp(step, run["step"], run["return"]))
                for run in runs
                if run["step"].iloc[0] <= step <= run["step"].iloc[-1]
            ])  # fmt: skip
            theirs = _official_at(curves, step * scale)
            rows.append({
                "algo": algo, "task": task, "step": int(step), "x": round(step * scale),
                "unit": reference.x_column, "seeds": len(yours),
                "mean": yours.mean() if len(yours) else np.nan,
                "std": yours.std(ddof=1) if len(yours) > 1 else np.nan,
                "official_seeds": len(theirs),
                "official_mean": theirs.mean() if len(theirs) else np.nan,
                "official_min": theirs.min() if len(theirs) else np.nan,
                "official_max": theirs.max() if len(theirs) else np.nan,
            })  # fmt: skip
    return pandas.DataFrame(
        rows,
        columns=["algo", "task", "step", "x", "unit", "seeds", "mean", "std", "official_seeds", "official_mean",
                 "official_min", "official_max"],
    )  # fmt: skip


def missing_tasks(records: pd.DataFrame, name: str) -> list[str]:
    """The tasks of ``records`` that the reference has no curves for."""
    known = set(load_reference(name)["task"])
    return sorted(str(task) for task in records["task"].unique() if reference_task(str(task)) not in known)
