"""Ctrl-C: a command saves its work and raises :class:`Interrupted`; :func:`sigint_deferred` keeps it out of a block."""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.type_aliases import MaybeCallback

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
    """Run the block to its end even if Ctrl-C comes meanwhile: the SIGINT is delivered after it."""
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


@contextmanager
def progress_bar_callback(callback: MaybeCallback, progress_bar: bool) -> Iterator[MaybeCallback]:
    """``callback`` with SB3's progress bar added when ``progress_bar``, closed however the block ends."""
    if not progress_bar:
        yield callback
        return
    from stable_baselines3.common.callbacks import BaseCallback, ConvertCallback, ProgressBarCallback

    bar = ProgressBarCallback()
    given = callback if isinstance(callback, list) else [] if callback is None else [callback]
    callbacks = [item if isinstance(item, BaseCallback) else ConvertCallback(item) for item in given]
    try:
        yield [*callbacks, bar]
    except BaseException:
        if getattr(bar, "pbar", None) is not None:
            bar.pbar.close()
        raise
