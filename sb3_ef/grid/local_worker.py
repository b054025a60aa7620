"""The set-up of a local pool worker, in a module of its own that imports only the standard library: a spawned
worker imports it before anything else, so the set-up is in force within a fraction of a second of its start."""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

#: Seconds between a local worker's checks that the driver that started it is still alive.
PARENT_CHECK_INTERVAL = 1.0
#: Exit status of a worker stopped by its driver (128 + SIGTERM).
STOPPED_STATUS = 128 + signal.SIGTERM

Result = TypeVar("Result")


class Stopped(SystemExit):
    """Raised in a worker by SIGTERM: unwinds the run (a file being written atomically is removed), then the
    worker exits without a traceback."""


def _stop(signum: int, frame: Any) -> None:
    raise Stopped(STOPPED_STATUS)


def set_up_worker(parent_pid: int) -> None:
    """Pool-worker initializer. Leave Ctrl-C to the driver (a terminal sends SIGINT to every process of the
    command), which ends its workers with SIGTERM (:class:`Stopped`); end this worker when the driver process is
    gone (killed, even by SIGKILL), so that no orphaned worker goes on training a run that the next invocation
    trains too. Checkpoint files are written atomically, so ending mid-write leaves the last complete checkpoint.

    A worker started inside :func:`sigint_held_for_workers` begins with SIGINT blocked: a Ctrl-C during its start
    is pending until here, where ignoring SIGINT discards it."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGTERM, _stop)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_INTERVAL)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


@contextlib.contextmanager
def sigint_held_for_workers() -> Iterator[None]:
    """Block SIGINT in the calling thread for the block. Processes started meanwhile inherit the mask, and so do
    threads, such as a process pool's manager thread, which starts the workers that replace finished ones: a Ctrl-C
    that comes while a worker starts (Python's start-up, before :func:`set_up_worker` runs) does not end it with a
    traceback. The calling process gets the Ctrl-C when the block ends. Where signal masks do not exist
    (Windows), the block runs as it is.

    multiprocessing's resource tracker is started first: starting it unblocks SIGINT in the thread that does."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def call_in_worker(task: Callable[[], Result]) -> Result:
    """``task()`` in a pool worker; stopped by the driver, the worker exits at once with :data:`STOPPED_STATUS` once
    the run has unwound (the pool sees a worker gone, not a result)."""
    try:
        return task()
    except Stopped:
        os._exit(STOPPED_STATUS)
