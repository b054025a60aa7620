"""Published learning curves, shipped with the package, and a user's runs put beside them.

Four references, read from ``reference_data/`` (sources, licences and units in ``reference_data/SOURCES.md``):

- ``"drqv2"``: DrQ-v2's official DMC curves (facebookresearch/drqv2, ``curves/``; 24 tasks, 8-10 seeds), episode
  return against **frames** (agent steps x action repeat 2);
- ``"tdmpc2"``: TD-MPC2's official DMC pixel results (nicklashansen/tdmpc2, ``results/tdmpc2-pixels/``; 12 tasks,
  3 seeds), episode return against **agent steps** (action repeat 2);
- ``"dreamerv3"``: Dreamer-v3's DMC vision scores (danijar/dreamerv3, ``scores/dmc_vision-dreamerv3.json.gz``;
  20 tasks, 8-10 seeds), the return of each training episode against **frames** (action repeat 2);
- ``"curl"``: the CURL scores of the same repository (``scores/dmc_vision-curl.json.gz``; 20 tasks, 10 seeds),
  episode return against **frames**, every 20k frames.

A run's evaluation records hold both ``step`` (agent steps) and ``frame``; each reference is compared on its own
axis (frames from the records' ``frame`` column, not from an assumed action repeat). Official seeds are
interpolated linearly between their points and never extrapolated beyond their last one.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from importlib import resources
from typing import TYPE_CHECKING

import numpy as np

from sb3_ef.analysis._optional import require
from sb3_ef.analysis.metrics import check_columns
from sb3_ef.analysis.records import RECORD_COLUMNS

if TYPE_CHECKING:
    import pandas as pd

REFERENCE_COLUMNS = ("task", "seed", "x", "return")
#: Returns of DMC tasks lie in [0, 1000]; records whose returns all lie in [0, 1] are likely something else.
UNIT_INTERVAL = (0.0, 1.0)


@dataclass(frozen=True)
class Reference:
    """A published set of learning curves: its data file, the unit of its x-axis and where it comes from."""

    label: str
    file: str
    x_column: str  # the records' column on the same axis: "frame" or "step"
    axis: str  # the x-axis label of the plots
    unit: str
    source: str
    action_repeat: int | None  # of the official runs, where the source records it


REFERENCES = {
    "drqv2": Reference(
        "DrQ-v2 (official)",
        "drqv2_dmc.csv.gz",
        "frame",
        "frames",
        "frames (agent steps x action repeat; official runs at action repeat 2)",
        "facebookresearch/drqv2 curves/ (MIT licence)",
        2,
    ),
    "tdmpc2": Reference(
        "TD-MPC2 (official)",
        "tdmpc2_pixels_dmc.csv.gz",
        "step",
        "agent steps",
        "agent steps (official runs at action repeat 2)",
        "nicklashansen/tdmpc2 results/tdmpc2-pixels/ (MIT licence)",
        2,
    ),
    "dreamerv3": Reference(
        "Dreamer-v3 (official)",
        "dreamerv3_dmc_vision.csv.xz",
        "frame",
        "frames",
        "frames (agent steps x action repeat; official runs at action repeat 2; one point per training episode)",
        "danijar/dreamerv3 scores/dmc_vision-dreamerv3.json.gz (MIT licence)",
        2,
    ),
    "curl": Reference(
        "CURL (Dreamer-v3's baseline scores)",
        "curl_dmc_vision.csv.gz",
        "frame",
        "frames",
        "frames (agent steps x action repeat; the source does not record the runs' action repeat)",
        "danijar/dreamerv3 scores/dmc_vision-curl.json.gz (MIT licence)",
        None,
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


@lru_cache(maxsize=len(REFERENCES))
def _read_reference(name: str) -> pd.DataFrame:
    pandas = require("pandas")
    reference = get_reference(name)
    with resources.as_file(resources.files("sb3_ef.analysis") / "reference_data" / reference.file) as path:
        table = pandas.read_csv(path)  # gzip or xz, by the file's suffix
    return table.rename(columns={reference.x_column: "x"})[list(REFERENCE_COLUMNS)]


def load_reference(name: str) -> pd.DataFrame:
    """The reference's curves: columns ``task, seed, x, return`` (``x`` in the reference's unit)."""
    return _read_reference(name).copy()


def _seed_values(official: pd.DataFrame, xs: np.ndarray) -> np.ndarray:
    """(official seeds, len(xs)): each seed's return at each x, linear between its points, NaN outside them."""
    seeds = list(official.groupby("seed"))
    values = np.full((len(seeds), len(xs)), np.nan)
    for index, (_, run) in enumerate(seeds):
        run = run.sort_values("x")
        x, y = run["x"].to_numpy(float), run["return"].to_numpy(float)
        inside = (xs >= x[0]) & (xs <= x[-1])
        values[index, inside] = np.interp(xs[inside], x, y)
    return values


def official_at(official: pd.DataFrame, x: float) -> np.ndarray:
    """Each official seed's return at ``x`` (linear between its points); seeds whose points do not span ``x`` are
    left out."""
    values = _seed_values(official, np.asarray([x], dtype=float))[:, 0]
    return values[~np.isnan(values)]


def official_band(official: pd.DataFrame, xs: np.ndarray) -> pd.DataFrame:
    """Mean, min and max over the official seeds at each of ``xs``, each seed interpolated as in
    :func:`official_at` (so seeds with grids of their own are averaged at the same x); an x no seed spans is left
    out."""
    pandas = require("pandas")
    xs = np.asarray(xs, dtype=float)
    values = _seed_values(official, xs)
    spanned = ~np.isnan(values).all(axis=0) if len(values) else np.zeros(len(xs), dtype=bool)
    values = values[:, spanned]
    return pandas.DataFrame({
        "x": xs[spanned], "mean": np.nanmean(values, axis=0), "min": np.nanmin(values, axis=0),
        "max": np.nanmax(values, axis=0),
    })  # fmt: skip


def _frames_per_step(group: pd.DataFrame) -> float:
    """The action repeat of a run's records (their ``frame`` over ``step``)."""
    moved = group[group["step"] > 0]
    return float((moved["frame"] / moved["step"]).median()) if not moved.empty else 1.0


def reference_table(records: pd.DataFrame, name: str, at: tuple[int, ...] = ()) -> pd.DataFrame:
    """Your mean at a step vs the official mean (min-max) at the same point, per algorithm and task of ``records``.

    ``at`` gives agent steps (as ``--at`` does everywhere); by default each algorithm's last step that all its seeds
    reached on that task. The comparison is made on the reference's own axis (``x``, in ``unit``: frames for
    DrQ-v2, Dreamer-v3 and CURL, read from the records' ``frame`` column, agent steps for TD-MPC2). Tasks the
    reference lacks are left out (see :func:`missing_tasks`).

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
            theirs = official_at(curves, step * scale)
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
    known = set(_read_reference(name)["task"])
    return sorted(str(task) for task in records["task"].unique() if reference_task(str(task)) not in known)


def unit_warnings(records: pd.DataFrame, name: str) -> list[str]:
    """Doubts about the units of ``records`` next to the reference, one sentence each (none when all looks right).

    The references hold DMC episode returns in [0, 1000] from runs at action repeat 2 (where recorded): returns
    that all lie in [0, 1] look like success rates or normalised scores, and ``frame == step`` means action repeat 1
    or a ``frame`` column that holds agent steps.
    """
    reference = get_reference(name)
    compared = records[~records["task"].astype(str).isin(missing_tasks(records, name))]
    warnings = []
    low, high = UNIT_INTERVAL
    returns = compared["return"]
    if len(returns) and returns.between(low, high).all():
        warnings.append(
            f"every return lies in [{low:g}, {high:g}], while {reference.label} holds DMC episode returns in "
            "[0, 1000]: if these are success rates or normalised scores, record episode returns to compare"
        )
    moved = compared[compared["step"] > 0]
    if len(moved) and (moved["frame"] == moved["step"]).all():
        repeat = "" if reference.action_repeat is None else f" (official runs: action repeat {reference.action_repeat})"
        warnings.append(
            f"frame equals step in every record: the runs used action repeat 1, or their frame column holds agent "
            f"steps{repeat}; the comparison is on {reference.axis}, read from the "
            f"records' {reference.x_column} column"
        )
    return warnings
