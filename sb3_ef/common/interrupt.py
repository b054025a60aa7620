"""Ctrl-C: the work done so far is saved, one line says what was kept, exit status 130.

A command that can save its state on Ctrl-C (``collect``'s episodes, ``pretrain``'s checkpoint, ``benchmark``'s
finished runs) catches ``KeyboardInterrupt`` there and raises :class:`Interrupted` with a line that says what was
kept; the ``sb3-ef`` console script prints ``sb3-ef <command>: interrupted[: what was kept]`` on stderr and exits
with :data:`INTERRUPTED_STATUS` (128 + SIGINT, as shells report it), without a traceback. :func:`sigint_deferred`
keeps Ctrl-C out of steps that must not be cut (a video encoder's packets, an optimiser step);
:func:`progress_bar_callback` closes ``learn``'s progress bar however training ends, so that Ctrl-C in ``learn`` gives
one ``KeyboardInterrupt`` with one traceback.
"""

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


@contextmanager
def progress_bar_callback(callback: MaybeCallback, progress_bar: bool) -> Iterator[MaybeCallback]:
    """``callback`` with SB3's progress bar added when ``progress_bar`` (pass it to SB3's ``learn`` with
    ``progress_bar=False``); the bar is closed when the block ends by an error or Ctrl-C. SB3 closes its bar only when
    training ends; one left open is closed at interpreter shutdown, where tqdm's rich bar can no longer import and
    prints a second traceback after the ``KeyboardInterrupt``'s."""
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
