"""Evaluation CSVs of rl-zoo3 runs, in the format ``sb3-ef analyze results`` reads.
``sb3-ef train`` records them; ``python -m sb3_ef.zoo.records logs results`` exports rl-zoo3's ``evaluations.npz``."""

from __future__ import annotations

import argparse
import glob
import json
import os
from collections.abc import Sequence
from pathlib import Path

from sb3_ef.analysis.records import RUN_RESULT_FILE, read_records, write_records
from sb3_ef.analysis.zoo_logs import EVALUATIONS_FILE, zoo_run_records
from sb3_ef.common.files import write_text_atomically


def run_records_path(save_path: str | os.PathLike, env_name: str) -> Path:
    """The evaluation CSV of the rl-zoo3 run folder ``save_path``."""
    return Path(save_path) / f"{env_name}.csv"


def run_result_path(save_path: str | os.PathLike, env_name: str) -> Path:
    """The file that marks the run finished: ``<env>/result.json``, in the folder named like its CSV."""
    return Path(save_path) / env_name / RUN_RESULT_FILE


def finish_run(save_path: str | os.PathLike, env_name: str, steps: int) -> None:
    """Mark the run finished at ``steps``, with its last recorded mean return."""
    rows = read_records(run_records_path(save_path, env_name))
    result = {"status": "finished", "steps": steps, "final_return": rows[-1]["return"] if rows else None}
    write_text_atomically(run_result_path(save_path, env_name), json.dumps(result, indent=1))


def export_records(log_folder: str, out: str, action_repeat: int | None = None) -> list[str]:
    """Write one evaluation CSV per rl-zoo3 run under ``log_folder`` that has evaluations; return their paths."""
    written = []
    for npz in sorted(glob.glob(os.path.join(log_folder, "*", "*", EVALUATIONS_FILE))):
        run_folder = os.path.dirname(npz)
        records = zoo_run_records(run_folder, action_repeat)
        path = os.path.join(out, str(records["algo"].iloc[0]), f"{os.path.basename(run_folder)}.csv")
        write_records(path, records.to_dict("records"))
        written.append(path)
    if not written:
        raise FileNotFoundError(f"No rl-zoo3 run with evaluations.npz under {log_folder} (train with --eval-freq > 0)")
    return written


def main(argv: Sequence[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m sb3_ef.zoo.records", description=__doc__.split("\n")[0])
    parser.add_argument("log_folder", help="rl-zoo3 log folder (train's -f, default 'logs')")
    parser.add_argument("out", help="folder for the evaluation CSVs")
    parser.add_argument("--action-repeat", type=int, help="env frames per agent step (default: the run's recorded one)")
    args = parser.parse_args(argv)
    paths = export_records(args.log_folder, args.out, args.action_repeat)
    print(f"{len(paths)} run(s) -> {args.out}")


if __name__ == "__main__":
    main()
