"""Evaluation CSVs of rl-zoo3 runs, in the format ``sb3-ef analyze results`` reads (:mod:`sb3_ef.analysis.records`).

``sb3-ef train`` records each evaluation as it happens (:func:`run_records_path`, :func:`finish_run`): a run folder
``<logs>/<algo>/<env>_<n>/`` holds ``<env>.csv``, one row per evaluation and each step once (a resumed run drops
the rows after its checkpoint before it evaluates them again), and ``<env>/result.json`` once the run has reached
its total step count, as ``sb3-ef benchmark`` marks a finished run (``analyze results --finished-only``).

Runs trained otherwise (rl-zoo3's own ``train``) can be exported from the ``evaluations.npz`` rl-zoo3's
EvalCallback writes into each run folder (steps, per-episode returns, successes when the env reports them; the
run's ``<env>/args.yml`` holds the env id and seed). Each run becomes one CSV ``<out>/<Algo>/<env>_<run>.csv``,
where ``<Algo>`` is the algorithm's class name (``drqv2_ef`` -> ``DrQv2EF``): the name
:class:`~sb3_ef.analysis.records.EvalRecorderCallback` writes, so runs of both kinds make one algorithm.

    python -m sb3_ef.zoo.records logs results     # results/DrQv2EF/dmc-cheetah-run-v0_1.csv, ...
    sb3-ef analyze results results
"""

from __future__ import annotations

import argparse
import csv
import glob
import io
import json
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import yaml
from rl_zoo3 import utils

from sb3_ef.analysis.records import RECORD_COLUMNS, RUN_RESULT_FILE, append_records, record_row
from sb3_ef.common.files import write_text_atomically
from sb3_ef.zoo.registration import register_algorithms


def run_records_path(save_path: str | os.PathLike, env_name: str) -> Path:
    """The evaluation CSV of the rl-zoo3 run folder ``save_path`` of env ``env_name`` (its folder form)."""
    return Path(save_path) / f"{env_name}.csv"


def run_result_path(save_path: str | os.PathLike, env_name: str) -> Path:
    """The file that marks the run finished: ``<env>/result.json``, in the folder named like its CSV."""
    return Path(save_path) / env_name / RUN_RESULT_FILE


def truncate_run_records(path: Path, last_step: int) -> None:
    """Keep the rows of the evaluation CSV ``path`` up to ``last_step`` (rewritten atomically; no file: nothing)."""
    if not path.is_file():
        return
    with open(path, newline="") as file:
        rows = [row for row in csv.DictReader(file) if int(row["step"]) <= last_step]
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=RECORD_COLUMNS, lineterminator="\r\n")  # as csv writes by default
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomically(path, text.getvalue())


def finish_run(save_path: str | os.PathLike, env_name: str, steps: int) -> None:
    """Mark the run finished at ``steps``: its ``result.json`` with the steps and the last recorded mean return
    (``null`` without an evaluation), written atomically."""
    records = run_records_path(save_path, env_name)
    rows = []
    if records.is_file():
        with open(records, newline="") as file:
            rows = list(csv.DictReader(file))
    result = {"status": "finished", "steps": steps, "final_return": float(rows[-1]["return"]) if rows else None}
    write_text_atomically(run_result_path(save_path, env_name), json.dumps(result, indent=1))


def algorithm_name(zoo_key: str) -> str:
    """The class name of the algorithm rl-zoo3 registers as ``zoo_key`` (``zoo_key`` itself if unknown)."""
    register_algorithms()
    algo_class = utils.ALGOS.get(zoo_key)
    return zoo_key if algo_class is None else algo_class.__name__


def run_records(run_folder: str, algo: str, action_repeat: int = 2) -> list[dict[str, object]]:
    """Rows ``algo, task, seed, step, frame, return, success`` of one rl-zoo3 run folder (mean over episodes)."""
    evaluations = np.load(os.path.join(run_folder, "evaluations.npz"))
    args_files = glob.glob(os.path.join(run_folder, "*", "args.yml"))
    if len(args_files) != 1:
        raise ValueError(f"Expected one <env>/args.yml in {run_folder}, found {len(args_files)}")
    with open(args_files[0]) as file:
        args = yaml.load(file, Loader=yaml.UnsafeLoader)  # rl-zoo3 writes an OrderedDict (Python tags)
    successes = evaluations["successes"] if "successes" in evaluations.files else None
    return [
        record_row(
            algo,
            args["env"],
            args["seed"],
            step,
            action_repeat,
            np.mean(returns),
            None if successes is None else np.mean(successes[index]),
        )
        for index, (step, returns) in enumerate(zip(evaluations["timesteps"], evaluations["results"], strict=True))
    ]


def export_records(log_folder: str, out: str, action_repeat: int = 2) -> list[str]:
    """Write one evaluation CSV per rl-zoo3 run under ``log_folder`` that has evaluations, under the algorithm's class
    name; return their paths.

    Existing CSVs are replaced, so exporting twice gives the same files.
    """
    written = []
    for npz in sorted(glob.glob(os.path.join(log_folder, "*", "*", "evaluations.npz"))):
        run_folder = os.path.dirname(npz)
        algo = algorithm_name(os.path.basename(os.path.dirname(run_folder)))
        path = os.path.join(out, algo, f"{os.path.basename(run_folder)}.csv")
        if os.path.exists(path):
            os.remove(path)
        append_records(path, run_records(run_folder, algo, action_repeat))
        written.append(path)
    if not written:
        raise FileNotFoundError(f"No rl-zoo3 run with evaluations.npz under {log_folder} (train with --eval-freq > 0)")
    return written


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m sb3_ef.zoo.records", description=__doc__.split("\n")[0])
    parser.add_argument("log_folder", help="rl-zoo3 log folder (train's -f, default 'logs')")
    parser.add_argument("out", help="folder for the evaluation CSVs")
    parser.add_argument("--action-repeat", type=int, default=2, help="env frames per agent step (frame column)")
    args = parser.parse_args(argv)
    paths = export_records(args.log_folder, args.out, args.action_repeat)
    print(f"{len(paths)} run(s) -> {args.out}")


if __name__ == "__main__":
    main()
