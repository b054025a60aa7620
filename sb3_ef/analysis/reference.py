"""Published learning curves (``reference_data/``, sources in its ``SOURCES.md``) and a user's runs beside them."""

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
#: DMC returns lie in [0, 1000]: records whose returns all lie in [0, 1] are likely something else.
UNIT_INTERVAL = (0.0, 1.0)


@dataclass(frozen=True)
class Reference:
    """A published set of learning curves: its data file, the unit of its x-axis and where it comes from."""

    label: str
    file: str
    x_column: str  # the records' column on the same axis: "frame" or "step"
    unit: str
    source: str
    action_repeat: int | None  # of the official runs, where the source records it
    version: str = "official"  # the agent's version (and model size) where more than one was published

    @property
    def axis(self) -> str:
        """The x-axis label of the plots."""
        return "frames" if self.x_column == "frame" else "agent steps"


_FRAMES = "frames (agent steps x action repeat; "
REFERENCES = {
    "drqv2": Reference(
        "DrQ-v2 (official)", "drqv2_dmc.csv.gz", "frame", _FRAMES + "official runs at action repeat 2)",
        "facebookresearch/drqv2 curves/ (MIT licence)", 2,
    ),
    "tdmpc2": Reference(
        "TD-MPC2 (official)", "tdmpc2_pixels_dmc.csv.gz", "step", "agent steps (official runs at action repeat 2)",
        "nicklashansen/tdmpc2 results/tdmpc2-pixels/ (MIT licence)", 2,
    ),
    "dreamerv3": Reference(
        "Dreamer-v3 (official, 2024 release, model 12M)", "dreamerv3_dmc_vision.csv.xz", "frame",
        _FRAMES + "official runs at action repeat 2; one point per training episode)",
        "danijar/dreamerv3 scores/dmc_vision-dreamerv3.json.gz added in commit 2411f7d (MIT licence)", 2,
        "2024 release (the 2025 article's scores), model 12M (the size12m preset its dmc_vision block sets)",
    ),
    "dreamerv3-2023": Reference(
        "Dreamer-v3 (official, 2023 release, model S)", "dmcvision_dreamerv3_2023.json.gz", "frame",
        _FRAMES + "official runs at action repeat 2; a point every 30k frames)",
        "danijar/dreamerv3 scores/data/dmcvision_dreamerv3.json.gz at commit 8fa35f8 (MIT licence)", 2,
        "2023 paper's release, model S (its dmc_vision preset: 512 recurrent units, CNN depth 32, 2 x 512 MLPs)",
    ),
    "curl": Reference(
        "CURL (Dreamer-v3's baseline scores)", "curl_dmc_vision.csv.gz", "frame",
        _FRAMES + "the source does not record the runs' action repeat)",
        "danijar/dreamerv3 scores/dmc_vision-curl.json.gz (MIT licence)", None,
    ),
}  # fmt: skip


def get_reference(name: str) -> Reference:
    """The reference called ``name``; a ``ValueError`` lists the known ones."""
    if name not in REFERENCES:
        raise ValueError(f"Unknown reference {name!r}: expected one of {sorted(REFERENCES)}")
    return REFERENCES[name]


def reference_task(task: str) -> str:
    """The references' name of a DMC task: ``dmc/cartpole_balance-v0`` -> ``cartpole-balance``."""
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


#: danijar/dreamerv3's task names that are not sb3-ef's (its 2023 scores file writes ``dmc_cup_catch``).
AUTHORS_TASKS = {"cup-catch": "ball-in-cup-catch"}


def _authors_task(task: str) -> str:
    """sb3-ef's name of a danijar/dreamerv3 task: ``dmc_walker_walk`` -> ``walker-walk``."""
    name = reference_task(re.sub(r"^dmc[a-z]*_", "", task))
    return AUTHORS_TASKS.get(name, name)


def authors_scores(path: str | os.PathLike, method: str = "dreamerv3") -> pd.DataFrame:
    """The runs of ``method`` in a danijar/dreamerv3 scores file, one row per point (``task, seed, x, return``)."""
    pandas = require("pandas")
    with gzip.open(path, "rt") as file:
        runs = json.load(file)
    frames = [
        pandas.DataFrame(
            {
                "task": _authors_task(str(run["task"])),
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
    """Seeds interpolated onto one grid up to ``end``: columns ``x``, ``mean``, ``std``, ``min``, ``max``, ``seeds``."""
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
    """Each official seed's return at ``x`` (linear between its points), of the seeds whose points span ``x``."""
    values = _seed_values(official, np.asarray([x], dtype=float))[:, 0]
    return values[~np.isnan(values)]


def _frames_per_step(group: pd.DataFrame) -> float:
    """The action repeat of a run's records (their ``frame`` over ``step``)."""
    moved = group[group["step"] > 0]
    return float((moved["frame"] / moved["step"]).median()) if not moved.empty else 1.0


def reference_table(records: pd.DataFrame, name: str, at: tuple[int, ...] = ()) -> pd.DataFrame:
    """Your mean at each step of ``at`` beside the official mean and min-max at the same point of its axis."""
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
    """Doubts about the units of ``records`` next to the reference: returns all in [0, 1], or ``frame == step``."""
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
