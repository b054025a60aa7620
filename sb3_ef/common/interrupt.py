"""Ctrl-C: the work done so far is saved, one line says what was kept, exit status 130.

A command that can save its state on Ctrl-C (``collect``'s episodes, ``pretrain``'s checkpoint, ``benchmark``'s
finished runs) catches ``KeyboardInterrupt`` there and raises :class:`Interrupted` with a line that says what was
kept; the ``sb3-ef`` console script prints ``sb3-ef <command>: interrupted[: what was kept]`` on stderr and exits
with :data:`INTERRUPTED_STATUS` (128 + SIGINT, as shells report it), without a traceback. :func:`sigint_deferred`
keeps Ctrl-C out of steps that must not be cut (a video encoder's packets, an optimiser step).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

#: The exit status of a command stopped by Ctrl-C (128 + SIGINT).
INTERRUPTED_STATUS = 130


class Interrupted(KeyboardInterrupt):
    """A ``KeyboardInterrupt`` after the state was saved; its message says what was kept and how to continue."""


def interrupted_line(command: str, interrupt: KeyboardInterrupt) -> str:
    """``<command>: interrupted``, then ``: <what was kept>`` if ``interrupt`` is an :class:`Interrupted` saying it."""
    detail = f": {interrupt}" if isinstance(interrupt, Interrupted) and str(interrupt) else ""
    return f"{command}: interrupted{detail}"


@contextmanager
def sigint_deferred() -> Iterator[None]:
    """Run the block to its end even if Ctrl-C comes meanwhile: the SIGINT is held and delivered after the block
    (as ``KeyboardInterrupt``, or to the handler that was installed). Outside the main thread, where SIGINT is never
    delivered, the block just runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda number, _frame: received.append(number))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            _deliver(previous)


def _deliver(handler: Any) -> None:
    """Hand a held SIGINT to ``handler`` (Python's default raises ``KeyboardInterrupt``; SIG_IGN drops it)."""
    if handler is signal.default_int_handler or handler in (signal.SIG_DFL, None):
        raise KeyboardInterrupt
    if callable(handler):
        handler(signal.SIGINT, None)
