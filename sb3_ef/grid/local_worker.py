"""The set-up of a local pool worker, standard library only so that a spawned worker applies it at once."""

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
    """Raised in a worker by SIGTERM: unwinds the run, then the worker exits without a traceback."""


def _stop(signum: int, frame: Any) -> None:
    raise Stopped(STOPPED_STATUS)


def set_up_worker(parent_pid: int) -> None:
    """Pool-worker initializer: Ctrl-C left to the driver, and the worker ends with it (no orphan runs)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # pending from sigint_held_for_workers: dropped
    signal.signal(signal.SIGTERM, _stop)

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(PARENT_CHECK_INTERVAL)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


@contextlib.contextmanager
def sigint_held_for_workers() -> Iterator[None]:
    """Block SIGINT while workers start, so they inherit the mask; the caller gets a Ctrl-C when the block ends."""
    if not hasattr(signal, "pthread_sigmask"):
        yield
        return
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()  # before the mask: starting it unblocks SIGINT
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def call_in_worker(task: Callable[[], Result]) -> Result:
    """``task()`` in a pool worker; stopped by the driver, it exits with :data:`STOPPED_STATUS` once unwound."""
    try:
        return task()
    except Stopped:
        os._exit(STOPPED_STATUS)
