"""One CSV format for every algorithm's evaluations: ``algo, task, seed, step, frame, return, success``."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback

from sb3_ef.common.files import write_text_atomically

RECORD_COLUMNS = ("algo", "task", "seed", "step", "frame", "return", "success")
#: The file a finished run writes into the folder named like its CSV (``run.csv`` -> ``run/result.json``).
RUN_RESULT_FILE = "result.json"


def record_row(
    algo: str,
    task: str,
    seed: int | None,
    step: int,
    action_repeat: int,
    mean_return: float,
    success: float | None,
) -> dict[str, object]:
    """One evaluation in the CSV format: ``frame = step * action_repeat``; an unknown seed or success is empty."""
    return {
        "algo": algo,
        "task": task,
        "seed": "" if seed is None else seed,
        "step": int(step),
        "frame": int(step) * action_repeat,
        "return": float(mean_return),
        "success": "" if success is None else float(success),
    }


def _check_rows(rows: list[dict[str, object]]) -> None:
    for row in rows:
        if set(row) != set(RECORD_COLUMNS):
            raise ValueError(f"Expected record columns {RECORD_COLUMNS}, got {tuple(row)}")


def write_records(path: str | os.PathLike, rows: list[dict[str, object]]) -> None:
    """Write an evaluation CSV of ``rows`` whole, replacing ``path`` only once it is complete."""
    _check_rows(rows)
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=RECORD_COLUMNS)
    writer.writeheader()
    writer.writerows(rows)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    write_text_atomically(path, text.getvalue())


def read_records(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The rows of an evaluation CSV (empty if it does not exist), with step, frame and return parsed."""
    if not os.path.isfile(path):
        return []
    with open(path, newline="") as file:
        rows = list(csv.DictReader(file))
    return [
        {**row, "step": int(row["step"]), "frame": int(row["frame"]), "return": float(row["return"])} for row in rows
    ]


def truncate_records(path: str | os.PathLike, last_step: int) -> None:
    """Keep only the evaluation rows up to ``last_step`` (the file replaced whole, removed when none is kept)."""
    rows = read_records(path)
    kept = [row for row in rows if row["step"] <= last_step]
    if not kept:
        Path(path).unlink(missing_ok=True)
    elif len(kept) < len(rows):
        write_records(path, kept)


def append_records(path: str | os.PathLike, rows: list[dict[str, object]]) -> None:
    """Append rows to an evaluation CSV (header when new); a file with another header is refused."""
    _check_rows(rows)
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    new_file = not os.path.exists(path) or os.path.getsize(path) == 0
    if not new_file:
        with open(path, newline="") as file:
            header = tuple(next(csv.reader(file), ()))
        if header != RECORD_COLUMNS:
            raise ValueError(f"{path} has header {header}, expected {RECORD_COLUMNS}: refusing to append to it")
    with open(path, "a", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=RECORD_COLUMNS)
        if new_file:
            writer.writeheader()
        writer.writerows(rows)


class EvalRecorderCallback(BaseCallback):
    """Append each evaluation of an ``EvalCallback`` (as its ``callback_after_eval``) to a CSV (docs/analysis.md).

    :param path: CSV file; created with a header, or appended to if it already holds records.
    :param algo: algorithm name; default the model's class name.
    :param task: task name; default the eval env's gymnasium id.
    :param seed: run seed; default ``model.seed``.
    :param action_repeat: env frames per agent step.
    """

    parent: EvalCallback | None

    def __init__(
        self,
        path: str | os.PathLike,
        algo: str | None = None,
        task: str | None = None,
        seed: int | None = None,
        action_repeat: int = 1,
        verbose: int = 0,
    ):
        super().__init__(verbose=verbose)
        if action_repeat < 1:
            raise ValueError(f"action_repeat must be >= 1, got {action_repeat}")
        self.path = os.fspath(path)
        self.algo, self.task, self.seed, self.action_repeat = algo, task, seed, action_repeat

    def _init_callback(self) -> None:
        if not isinstance(self.parent, EvalCallback):
            raise TypeError(
                "EvalRecorderCallback must be passed as EvalCallback(..., callback_after_eval=recorder), "
                f"got parent {type(self.parent).__name__}"
            )
        if self.algo is None:
            self.algo = type(self.model).__name__
        if self.task is None:
            spec = self.parent.eval_env.get_attr("spec", indices=[0])[0]
            self.task = spec.id if spec is not None else "unknown"
        if self.seed is None:
            self.seed = self.model.seed

    def _on_step(self) -> bool:
        assert self.parent is not None and self.algo is not None and self.task is not None  # set by _init_callback
        successes = self.parent._is_success_buffer  # final info["is_success"] values, kept until the next evaluation
        row = record_row(
            self.algo,
            self.task,
            self.seed,
            self.num_timesteps,
            self.action_repeat,
            self.parent.last_mean_reward,
            float(np.mean(successes)) if successes else None,
        )
        append_records(self.path, [row])
        if self.verbose >= 1:
            print(f"Recorded evaluation at step {self.num_timesteps} to {self.path}")
        return True
