"""Close matches of a misspelt name, for the error that names it (the standard library only: the registry uses it)."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


def closest_names(name: str, choices: Iterable[str], count: int = 3, cutoff: float = 0.6) -> list[str]:
    """Up to ``count`` of ``choices`` at least ``cutoff`` similar to ``name`` (difflib's ratio), best first."""
    return difflib.get_close_matches(name, list(choices), n=count, cutoff=cutoff)


def did_you_mean(name: str, choices: Iterable[str], cutoff: float = 0.6) -> str:
    """`` (did you mean 'a' or 'b'?)`` for the close matches of ``name``, or ``""`` when none is close."""
    matches = closest_names(name, choices, cutoff=cutoff)
    return f" (did you mean {' or '.join(repr(match) for match in matches)}?)" if matches else ""
