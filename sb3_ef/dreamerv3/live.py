"""Objects of this process handed to sheeprl's plain-valued Hydra configuration by a token looked up here."""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

_OBJECTS: dict[str, Any] = {}
_COUNTER = itertools.count()


@contextmanager
def registered(obj: Any) -> Iterator[str]:
    """Register ``obj`` for the duration of the block and yield its token."""
    token = f"{type(obj).__name__}-{next(_COUNTER)}"
    _OBJECTS[token] = obj
    try:
        yield token
    finally:
        del _OBJECTS[token]


def lookup(token: str) -> Any:
    """The object registered under ``token``."""
    try:
        return _OBJECTS[token]
    except KeyError:
        raise KeyError(
            f"No live object {token!r}: a sheeprl configuration written by sb3_ef.dreamerv3 names objects of the "
            "process that trained it; train or resume through sb3_ef.dreamerv3.DreamerV3"
        ) from None
