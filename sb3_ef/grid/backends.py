"""Where runs execute: a local process pool, or a Ray cluster (the optional ``ray`` extra)."""

from __future__ import annotations

import functools
import os
import time
import traceback
from collections import deque
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import get_context
from typing import Any

from sb3_ef.grid.grid import RunSpec
from sb3_ef.grid.local_worker import call_in_worker, set_up_worker, sigint_held_for_workers
from sb3_ef.grid.run import RunOptions, RunPaths, RunResult, execute_run, store_result

#: What ``execute`` yields: ``("start" | "retry" | "finish", spec, None | error | result)``; leaving early stops runs.
Event = tuple[str, RunSpec, Any]

#: Seconds the driver waits for a stopped local worker to end before it kills it.
STOP_TIMEOUT = 5.0


def _failure(spec: RunSpec, error: BaseException) -> RunResult:
    # The last line names the error (a Ray task error's message holds the remote traceback before it).
    message = "".join(traceback.format_exception_only(type(error), error)).strip().splitlines()[-1]
    return RunResult(spec.run_id, "failed", error=message)


class LocalBackend:
    """Runs in a pool of spawned processes, one per run; a worker that dies fails its runs and the pool is rebuilt."""

    def __init__(
        self,
        out: str | os.PathLike,
        workers: int = 1,
        threads: int = 1,
        device: str = "auto",
        retries: int = 1,
        keep_checkpoints: int | None = 2,
    ):
        if workers < 1 or threads < 1 or retries < 0:
            raise ValueError(f"workers and threads must be >= 1 and retries >= 0, got {workers}, {threads}, {retries}")
        self.out, self.workers, self.retries = out, workers, retries
        self.run_kwargs: RunOptions = {"threads": threads, "device": device, "keep_checkpoints": keep_checkpoints}

    def _pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            self.workers,
            mp_context=get_context("spawn"),
            max_tasks_per_child=1,
            initializer=set_up_worker,
            initargs=(os.getpid(),),
        )

    def execute(self, specs: Sequence[RunSpec]) -> Iterator[Event]:
        queue, attempts = deque(specs), dict.fromkeys((spec.run_id for spec in specs), 0)
        running: dict[Future, RunSpec] = {}
        pool, completed = self._pool(), False
        try:
            while queue or running:
                while queue and len(running) < self.workers:
                    spec = queue.popleft()
                    task = functools.partial(execute_run, spec, self.out, **self.run_kwargs)
                    with sigint_held_for_workers():  # the pool starts its workers, and its manager thread, here
                        running[pool.submit(call_in_worker, task)] = spec
                    yield "start", spec, None
                done, _ = wait(running, return_when=FIRST_COMPLETED)
                broken = False
                for future in done:
                    spec = running.pop(future)
                    try:
                        yield "finish", spec, future.result()
                    except Exception as error:  # the run's own error, or its worker died
                        broken |= isinstance(error, BrokenProcessPool)
                        attempts[spec.run_id] += 1
                        if attempts[spec.run_id] > self.retries:
                            yield "finish", spec, _failure(spec, error)
                        else:
                            queue.appendleft(spec)
                            yield "retry", spec, error
                if broken:
                    pool.shutdown(cancel_futures=True)
                    pool = self._pool()
            completed = True
        finally:
            if completed:
                pool.shutdown()
            else:  # Ctrl-C, or the caller stopped iterating: end the runs in flight now
                _stop(pool)


def _stop(pool: ProcessPoolExecutor) -> None:
    """End the runs in flight of ``pool`` now: SIGTERM, SIGKILL after :data:`STOP_TIMEOUT`."""
    # ProcessPoolExecutor has no public way to end running tasks before Python 3.14 (terminate_workers).
    processes = list((getattr(pool, "_processes", None) or {}).values())
    for process in processes:
        process.terminate()
    deadline = time.monotonic() + STOP_TIMEOUT
    for process in processes:
        process.join(max(0.0, deadline - time.monotonic()))
        if process.is_alive():
            process.kill()
            process.join()
    pool.shutdown(cancel_futures=True)


def _execute_on_node(spec: RunSpec, out: str, **run_kwargs: Any) -> RunResult:
    """``execute_run`` inside a Ray task; the result names the node that ran it."""
    import ray

    return execute_run(spec, out, node=ray.get_runtime_context().get_node_id(), **run_kwargs)


class RayBackend:
    """One Ray task per run on the cluster at ``address``; the driver writes each run's records too (no shared disk)."""

    def __init__(
        self,
        out: str | os.PathLike,
        address: str | None = None,
        threads: int = 1,
        gpus: float = 0.0,
        device: str = "auto",
        retries: int = 1,
        keep_checkpoints: int | None = 2,
    ):
        if threads < 1 or gpus < 0 or retries < 0:
            raise ValueError(f"threads must be >= 1, gpus >= 0 and retries >= 0, got {threads}, {gpus}, {retries}")
        # Absolute, so that workers whose working directory differs find the same folder (a shared filesystem).
        self.out = os.path.abspath(out)
        self.address, self.threads, self.gpus, self.retries = address, threads, gpus, retries
        self.run_kwargs: RunOptions = {"threads": threads, "device": device, "keep_checkpoints": keep_checkpoints}

    def capacity(self, resources: dict[str, float]) -> int:
        """How many runs the cluster holds at once with each run's CPU and GPU request (at least one)."""
        slots = resources.get("CPU", 0) // self.threads
        if self.gpus > 0:
            slots = min(slots, resources.get("GPU", 0) // self.gpus)
        return max(1, int(slots))

    def execute(self, specs: Sequence[RunSpec]) -> Iterator[Event]:
        import ray

        started_here = not ray.is_initialized()
        if started_here:
            ray.init(address=self.address, log_to_driver=False)
        task = ray.remote(num_cpus=self.threads, num_gpus=self.gpus, max_retries=self.retries, retry_exceptions=True)(
            _execute_on_node
        )
        capacity = self.capacity(ray.cluster_resources())
        queue: deque[RunSpec] = deque(specs)
        running: dict[Any, RunSpec] = {}
        try:
            while queue or running:
                while queue and len(running) < capacity:
                    spec = queue.popleft()
                    # Ray's stub of remote() takes positional arguments only; Ray passes keywords on.
                    running[task.remote(spec, self.out, **self.run_kwargs)] = spec  # type: ignore[misc]
                    yield "start", spec, None
                [ref], _ = ray.wait(list(running), num_returns=1)
                spec = running.pop(ref)
                try:
                    result = ray.get(ref)
                except Exception as error:  # RayTaskError (the run raised) or a crashed worker, after the retries
                    result = _failure(spec, error)
                else:
                    store_result(RunPaths.of(self.out, spec), result)
                yield "finish", spec, result
        finally:
            for ref in running:
                ray.cancel(ref, force=True)
            if started_here:
                ray.shutdown()
