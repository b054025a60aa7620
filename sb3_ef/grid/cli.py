"""``sb3-ef benchmark``: train a grid of runs (algorithms x tasks x seeds) locally or on a Ray cluster."""

from __future__ import annotations

import argparse
import math
import os
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

from sb3_ef.common.interrupt import Interrupted
from sb3_ef.grid.grid import BACKENDS

if TYPE_CHECKING:
    from sb3_ef.grid.grid import RunSpec


def at_least(minimum: int | float, kind: Callable[[str], int | float] = int) -> Callable[[str], int | float]:
    """An argparse ``type``: a number of ``kind`` that is at least ``minimum``."""

    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            expected = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not math.isfinite(value) or value < minimum:
            raise argparse.ArgumentTypeError(f"must be >= {minimum}, got {text}")
        return value

    return parse


def keep_count(text: str) -> int | None:
    """``--keep-checkpoints``: a count >= 1, or ``all`` (``None``)."""
    if text == "all":
        return None
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"expected a count >= 1 or 'all', got {text!r}")
    return int(text)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="sb3-ef benchmark", description=__doc__.split("\n")[0])
    parser.add_argument("grid", help="grid file (YAML with a list 'grids' of blocks; see docs/benchmark.md)")
    parser.add_argument("--out", required=True, help="results folder: evaluation CSVs, checkpoints, run results")
    parser.add_argument("--runs", nargs="+", metavar="GLOB", help="only the runs whose id matches, e.g. 'drqv2/*'")
    parser.add_argument("--backend", choices=BACKENDS, default="local", help="local process pool or Ray cluster")
    parser.add_argument("--workers", type=at_least(1), default=1, help="local backend: runs in parallel")
    parser.add_argument("--threads", type=at_least(1), default=1, help="torch threads per run (Ray: CPUs per task too)")
    parser.add_argument("--address", help="Ray: cluster address ('auto', host:port); default: start Ray here")
    parser.add_argument("--gpus", type=at_least(0, float), default=0.0, help="Ray: GPUs per task (fractions share one)")
    parser.add_argument("--retries", type=at_least(0), default=1, help="attempts after a failure (each resumes)")
    parser.add_argument("--device", default="auto", help="torch device of each run")
    parser.add_argument(
        "--keep-checkpoints", type=keep_count, default=2, metavar="N|all",
        help="newest checkpoints kept per run while it trains, deleted when it ends; all: every one, kept for good",
    )  # fmt: skip
    parser.add_argument(
        "--dry-run", action="store_true",
        help="list the runs, their status and expected hours, and check each row's start (env, data, arguments)",
    )  # fmt: skip
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``sb3-ef benchmark``: 1 when a run failed, 2 when the grid has problems, else 0."""
    args = build_parser().parse_args(argv)
    from sb3_ef.grid.grid import GridError, load_grid, read_grid_file

    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out!r} is a file: expected the results folder (created when missing)")
    read_grid_file(args.grid)  # a broken file is reported before the heavy imports
    try:
        return _run(args, load_grid(args.grid))
    except GridError as error:
        if os.environ.get("SB3_EF_TRACEBACK") == "1":
            raise
        count = len(error.problems)
        lines = [f"{count} problem{'s' * (count > 1)} in the grid, nothing trained:", *error.problems]
        print("sb3-ef benchmark: error: " + "\n  ".join(lines), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        raise Interrupted(
            f"finished runs are kept in {args.out}; rerun the same command to skip them and resume the others from "
            "their last checkpoint"
        ) from None


def _run(args: argparse.Namespace, runs: list[RunSpec]) -> int:
    """Select, plan or train the runs (rows checked here unless on Ray, whose nodes may hold other data)."""
    from sb3_ef.grid.checks import check_rows
    from sb3_ef.grid.grid import GridError, select_runs
    from sb3_ef.grid.runner import plan_table

    if args.runs:
        runs = select_runs(runs, args.runs)
    if args.dry_run:
        print(plan_table(runs, args.out), flush=True)
    problems = check_rows(runs, args.out, args.device) if args.dry_run or args.backend == "local" else []
    if problems:
        raise GridError(problems)
    if args.dry_run:
        return 0
    from sb3_ef.grid.runner import run_benchmark

    names = ("backend", "workers", "threads", "device", "retries", "address", "gpus", "keep_checkpoints")
    results = run_benchmark(runs, args.out, **{name: getattr(args, name) for name in names})
    return int(any(result.status == "failed" for result in results))


if __name__ == "__main__":
    raise SystemExit(main())
