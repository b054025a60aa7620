"""Published learning curves, shipped with the package, and a user's runs put beside them.

Five references, read from ``reference_data/`` (sources, licences and units in ``reference_data/SOURCES.md``); each
names the agent's version (and, for Dreamer-v3, its model size) and the source commit:

- ``"drqv2"``: DrQ-v2's official DMC curves (facebookresearch/drqv2, ``curves/``; 24 tasks, 8-10 seeds), episode
  return against **frames** (agent steps x action repeat 2);
- ``"tdmpc2"``: TD-MPC2's official DMC pixel results (nicklashansen/tdmpc2, ``results/tdmpc2-pixels/``; 12 tasks,
  3 seeds), episode return against **agent steps** (action repeat 2);
- ``"dreamerv3"``: Dreamer-v3's DMC vision scores of the authors' 2024 release (danijar/dreamerv3,
  ``scores/dmc_vision-dreamerv3.json.gz``; 20 tasks, 8-10 seeds), the return of each training episode against
  **frames** (action repeat 2);
- ``"dreamerv3-2023"``: those of the 2023 paper's release (``scores/data/dmcvision_dreamerv3.json.gz`` of its
  history), the agent that sheeprl's Dreamer-v3 and the zoo's ``dreamerv3`` entries follow, read as the authors
  wrote the file (:func:`authors_scores`), on the same axis;
- ``"curl"``: the CURL scores of the same repository (``scores/dmc_vision-curl.json.gz``; 20 tasks, 10 seeds),
  episode return against **frames**, every 20k frames.

A run's evaluation records hold both ``step`` (agent steps) and ``frame``; each reference is compared on its own
axis (frames from the records' ``frame`` column, not from an assumed action repeat). Seeds are put on one common
grid (:func:`seed_band`): each interpolated linearly between its points, never extrapolated beyond its first or last
one.
"""

from __future__ import annotations

import gzip
import json
import os
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
    version: str = "official"  # the agent's version (and model size) where more than one was published


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
        "Dreamer-v3 (official, 2024 release, model 12M)",
        "dreamerv3_dmc_vision.csv.xz",
        "frame",
        "frames",
        "frames (agent steps x action repeat; official runs at action repeat 2; one point per training episode)",
        "danijar/dreamerv3 scores/dmc_vision-dreamerv3.json.gz at commit e3f0224 (MIT licence)",
        2,
        "2024 release (the 2025 article's scores), model 12M (the size12m preset its dmc_vision block sets)",
    ),
    "dreamerv3-2023": Reference(
        "Dreamer-v3 (official, 2023 release, model S)",
        "dmcvision_dreamerv3_2023.json.gz",
        "frame",
        "frames",
        "frames (agent steps x action repeat; official runs at action repeat 2; a point every 30k frames)",
        "danijar/dreamerv3 scores/data/dmcvision_dreamerv3.json.gz at commit 8fa35f8 (MIT licence)",
        2,
        "2023 paper's release, model S (its dmc_vision preset: 512 recurrent units, CNN depth 32, 2 x 512 MLPs)",
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


def check_reference_data(name: str) -> None:
    """Raise ``FileNotFoundError`` naming the file to add when the data of reference ``name`` is not installed."""
    reference = get_reference(name)
    if not (resources.files("sb3_ef.analysis") / "reference_data" / reference.file).is_file():
        raise FileNotFoundError(
            f"The reference {name!r} ({reference.label}) needs its data file, not installed here: save "
            f"{reference.source.removesuffix(' (MIT licence)')} as it is to sb3_ef/analysis/reference_data/"
            f"{reference.file} (reference_data/SOURCES.md)"
        )


def authors_scores(path: str | os.PathLike, method: str = "dreamerv3") -> pd.DataFrame:
    """The scores file of danijar/dreamerv3 (gzipped JSON: a list of runs, each ``task`` as ``dmc_<domain>_<task>``,
    ``method``, ``seed``, ``xs`` and ``ys``), the runs of ``method`` one row per point: columns ``task`` (sb3-ef's
    name: ``walker-walk``), ``seed``, ``x`` (the file's ``xs``) and ``return`` (its ``ys``, rounded to 0.01 as in
    the shipped CSVs)."""
    pandas = require("pandas")
    with gzip.open(path, "rt") as file:
        runs = json.load(file)
    frames = [
        pandas.DataFrame(
            {
                "task": reference_task(re.sub(r"^dmc[a-z]*_", "", str(run["task"]))),
                "seed": int(run["seed"]),
                "x": np.asarray(run["xs"], dtype=np.int64),
                "return": np.round(np.asarray(run["ys"], dtype=float), 2),
            }
        )
        for run in runs
        if run.get("method", method) == method
    ]
    if not frames:
        raise ValueError(f"{path} holds no runs of the method {method!r}")
    return pandas.concat(frames, ignore_index=True)


@lru_cache(maxsize=len(REFERENCES))
def _read_reference(name: str) -> pd.DataFrame:
    pandas = require("pandas")
    reference = get_reference(name)
    check_reference_data(name)
    with resources.as_file(resources.files("sb3_ef.analysis") / "reference_data" / reference.file) as path:
        if reference.file.endswith(".json.gz"):
            return authors_scores(path)
        table = pandas.read_csv(path)  # gzip or xz, by the file's suffix
    return table.rename(columns={reference.x_column: "x"})[list(REFERENCE_COLUMNS)]


def load_reference(name: str) -> pd.DataFrame:
    """The reference's curves: columns ``task, seed, x, return`` (``x`` in the reference's unit)."""
    return _read_reference(name).copy()


def _seed_values(curves: pd.DataFrame, xs: np.ndarray, x: str = "x", y: str = "return") -> np.ndarray:
    """(seeds, len(xs)): each seed's ``y`` at each of ``xs``, linear between its points, NaN outside them."""
    seeds = list(curves.groupby("seed"))
    values = np.full((len(seeds), len(xs)), np.nan)
    for index, (_, run) in enumerate(seeds):
        run = run.sort_values(x)
        points, ys = run[x].to_numpy(float), run[y].to_numpy(float)
        inside = (xs >= points[0]) & (xs <= points[-1])
        values[index, inside] = np.interp(xs[inside], points, ys)
    return values


def seed_band(
    curves: pd.DataFrame, x: str = "x", y: str = "return", end: float = np.inf, points: int | None = None
) -> pd.DataFrame:
    """Seeds (``seed``, ``x``, ``y``) on one common grid where every seed has points on both sides (up to ``end``):
    the union of their points, or ``points`` evenly spaced x's; each seed interpolated linearly onto it, none
    extrapolated. Seeds that log at other steps (another evaluation grid, bursts of training episodes) thus average
    at the same x, and the band does not jump where a seed's points start or stop. An even grid suits curves of one
    point per training episode (Dreamer-v3's), whose consecutive episodes differ by a lot: the union would draw
    every episode of a burst.

    :return: columns ``x``, ``mean``, ``std`` (over seeds, ``ddof=1``; NaN for one seed), ``min``, ``max``,
        ``seeds``.
    """
    pandas = require("pandas")
    spans = curves.groupby("seed")[x].agg(["min", "max"])
    low, high = float(spans["min"].max()), min(float(spans["max"].min()), end)
    given = curves[x].to_numpy(float)
    union = np.unique(given[(given >= low) & (given <= high)])
    xs = union if points is None or len(union) < 2 else np.linspace(union[0], union[-1], points)
    values = _seed_values(curves, xs, x, y)
    return pandas.DataFrame({
        "x": xs, "mean": values.mean(axis=0), "std": values.std(axis=0, ddof=1) if len(values) > 1 else np.nan,
        "min": values.min(axis=0), "max": values.max(axis=0), "seeds": len(values),
    })  # fmt: skip


def official_at(official: pd.DataFrame, x: float) -> np.ndarray:
    """Each official seed's return at ``x`` (linear between its points); seeds whose points do not span ``x`` are
    left out."""
    values = _seed_values(official, np.asarray([x], dtype=float))[:, 0]
    return values[~np.isnan(values)]


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

    :return: columns ``reference`` (its label: agent, version, model size), ``algo, task, step, x, unit, seeds, mean,
        std, official_seeds, official_mean, official_min, official_max``; ``official_*`` are NaN (and
        ``official_seeds`` 0) where no official seed reached ``x``.
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
                "reference": reference.label, "algo": algo, "task": task, "step": int(step), "x": round(step * scale),
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
        columns=["reference", "algo", "task", "step", "x", "unit", "seeds", "mean", "std", "official_seeds",
                 "official_mean", "official_min", "official_max"],
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
