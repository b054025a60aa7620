"""Run a grid: skip finished runs, execute the rest on a backend, print progress and a summary table."""

from __future__ import annotations

import os
import statistics
from collections.abc import Callable, Sequence
from typing import TypedDict

from sb3_ef.grid.backends import LocalBackend, RayBackend
from sb3_ef.grid.grid import BACKENDS, RunSpec, check_unique
from sb3_ef.grid.run import RunPaths, RunResult, read_result


class _BackendOptions(TypedDict):
    threads: int
    device: str
    retries: int
    keep_checkpoints: int | None


def _score(result: RunResult) -> str:
    if result.final_return is None or not result.records:
        return "no evaluation"
    return f"return {result.final_return:.1f} at step {result.records[-1]['step']}"


def progress_line(event: str, spec: RunSpec, detail: RunResult | BaseException | None, index: int, total: int) -> str:
    """One line per event: ``[ 3/12] done   <run id>  812.3 s  return 803.1 at step 20000``."""
    word = detail.status if isinstance(detail, RunResult) else event  # a finish reads "done" or "failed"
    head = f"[{index:>{len(str(total))}}/{total}] {word:<7} {spec.run_id}"
    if isinstance(detail, BaseException):
        return f"{head}  {type(detail).__name__}: {detail} (retrying)"
    if detail is None:
        return head
    if detail.status == "failed":
        return f"{head}  {detail.error}"
    if detail.status == "skipped":
        return f"{head}  finished earlier: {_score(detail)}"
    resumed = "" if detail.resumed_from is None else f" (resumed from step {detail.resumed_from})"
    return f"{head}  {detail.duration_s:.1f} s  {_score(detail)}{resumed}"


def _table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(str(cell)) for cell in column) for column in zip(header, *rows, strict=True)]
    lines = [header, ["-" * width for width in widths], *rows]
    return "\n".join(
        "  ".join(str(cell).ljust(width) for cell, width in zip(line, widths, strict=True)) for line in lines
    )


def summary_table(runs: Sequence[RunSpec], results: Sequence[RunResult]) -> str:
    """Per algorithm and task: runs finished and failed, final return mean +- std over seeds, training hours."""
    groups: dict[tuple[str, str], list[RunResult]] = {}
    for spec, result in zip(runs, results, strict=True):
        groups.setdefault((spec.label, spec.task), []).append(result)
    rows = []
    for (label, task), group in groups.items():
        finished = [result for result in group if result.status != "failed"]
        returns = [result.final_return for result in finished if result.final_return is not None]
        spread = f" +- {statistics.stdev(returns):.1f}" if len(returns) > 1 else ""
        score = f"{statistics.mean(returns):.1f}{spread}" if returns else "-"
        hours = sum(result.duration_s for result in finished) / 3600
        rows.append(
            [label, task, f"{len(finished)}/{len(group)}", str(len(group) - len(finished)), score, f"{hours:.2f}"]
        )
    return _table(["algorithm", "task", "finished", "failed", "final return", "hours"], rows)


def run_status(out: str | os.PathLike, spec: RunSpec) -> str:
    """``finished``, ``partial`` (records or checkpoints from an interrupted attempt) or ``new``."""
    paths = RunPaths.of(out, spec)
    if paths.result.is_file():
        return "finished"
    return "partial" if paths.records.is_file() or paths.checkpoints.is_dir() else "new"


def plan_table(runs: Sequence[RunSpec], out: str | os.PathLike) -> str:
    """Per algorithm and task: runs by status, steps per run and expected hours, with a total line."""
    groups: dict[tuple[str, str], list[RunSpec]] = {}
    for spec in runs:
        groups.setdefault((spec.label, spec.task), []).append(spec)
    rows, total_hours = [], 0.0
    for (label, task), group in groups.items():
        statuses = [run_status(out, spec) for spec in group]
        counts = ", ".join(
            f"{statuses.count(name)} {name}" for name in ("finished", "partial", "new") if name in statuses
        )
        rates = [spec.steps_per_second or 0.0 for spec in group]
        hours = "-"
        if all(rates):
            group_hours = sum(spec.n_timesteps / rate for spec, rate in zip(group, rates, strict=True)) / 3600
            total_hours += group_hours
            hours = f"{group_hours:.1f}"
        rows.append([label, task, str(len(group)), counts, str(group[0].n_timesteps), hours])
    unknown = sorted({spec.label for spec in runs if not spec.steps_per_second})
    total = "-" if len(unknown) == len({spec.label for spec in runs}) else f"{total_hours:.1f}"
    if unknown and total != "-":
        total = f">= {total}"
    rows.append(["total", f"{len(groups)} algorithm-task pairs", str(len(runs)), "", "", total])
    table = _table(["algorithm", "task", "runs", "status", "steps/run", "expected hours"], rows)
    if unknown:
        table += (
            f"\nexpected hours unknown for {', '.join(unknown)}: give each algorithm steps_per_second (agent steps "
            "per second of one run on this machine) in the grid file, e.g. measured with a short run"
        )
    return table


def run_benchmark(
    runs: Sequence[RunSpec],
    out: str | os.PathLike,
    backend: str = "local",
    workers: int = 1,
    threads: int = 1,
    device: str = "auto",
    retries: int = 1,
    address: str | None = None,
    gpus: float = 0.0,
    keep_checkpoints: int | None = 2,
    log: Callable[[str], None] = print,
) -> list[RunResult]:
    """Execute ``runs`` into ``out`` (finished ones skipped, interrupted ones resumed); results in order."""
    if backend not in BACKENDS:
        raise ValueError(f"Unknown backend {backend!r}: expected one of {BACKENDS}")
    if keep_checkpoints is not None and keep_checkpoints < 1:
        raise ValueError(f"keep_checkpoints must be >= 1 or None (all), got {keep_checkpoints}")
    check_unique(runs)
    position = {spec.run_id: index for index, spec in enumerate(runs, start=1)}
    results: dict[str, RunResult] = {}
    pending = []
    for spec in runs:
        stored = read_result(RunPaths.of(out, spec))
        if stored is None:
            pending.append(spec)
        else:
            results[spec.run_id] = stored
            log(progress_line("skip", spec, stored, position[spec.run_id], len(runs)))
    if pending:
        options = _BackendOptions(threads=threads, device=device, retries=retries, keep_checkpoints=keep_checkpoints)
        executor: LocalBackend | RayBackend
        if backend == "local":
            executor = LocalBackend(out, workers=workers, **options)
        else:
            executor = RayBackend(out, address=address, gpus=gpus, **options)
        for event, spec, detail in executor.execute(pending):
            if event == "finish":
                results[spec.run_id] = detail
            log(progress_line(event, spec, detail, position[spec.run_id], len(runs)))
    ordered = [results[spec.run_id] for spec in runs]
    log(summary_table(runs, ordered))
    return ordered
