"""Files written whole or not at all: a temporary file beside the target, flushed and renamed over it."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

#: Suffix of the temporary files; a leftover one (from a killed process) is never read as a result.
TEMPORARY_SUFFIX = ".tmp"


def temporary_path(path: str | os.PathLike) -> Path:
    """The temporary file beside ``path`` that :func:`atomic_path` writes first (keeping ``path``'s suffix)."""
    path = Path(path)
    return path.with_name(f".{path.stem}{TEMPORARY_SUFFIX}{path.suffix}")


def _fsync(path: Path) -> None:
    with open(path, "rb") as file:
        os.fsync(file.fileno())


def _fsync_folder(folder: Path) -> None:
    """Flush ``folder``'s entries (a rename in it) to disk; a no-op where folders cannot be opened (Windows)."""
    try:
        descriptor = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path to write ``path``'s content to, renamed to ``path`` on success, else removed."""
    path = Path(path)
    temporary = temporary_path(path)
    try:
        yield temporary
        _fsync(temporary)
        os.replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
    _fsync_folder(path.parent)


def write_atomically(path: str | os.PathLike, write: Callable[[Any], Any]) -> None:
    """``write(file)`` into a binary file that replaces ``path`` only once it is complete (:func:`atomic_path`)."""
    with atomic_path(path) as temporary, open(temporary, "wb") as file:
        write(file)
        file.flush()


def write_text_atomically(path: str | os.PathLike, text: str) -> None:
    """``text`` (UTF-8) into ``path``, complete or not at all."""
    write_atomically(path, lambda file: file.write(text.encode("utf-8")))


def refuse_files_in(folder: str, why: str) -> None:
    """Raise ``FileExistsError`` when ``folder`` (or a subfolder) holds a file; ``why`` ends the message."""
    files = sorted(os.path.relpath(os.path.join(d, f), folder) for d, _, fs in os.walk(folder) for f in fs)
    if files:
        raise FileExistsError(f"{folder} is not empty ({len(files)} files, e.g. {files[0]}){why}")
