"""A variant's written-out constructor arguments, passed on to the class it extends."""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import Any


def base_arguments(base: type, arguments: Mapping[str, Any], **overrides: Any) -> dict[str, Any]:
    """The entries of ``arguments`` that ``base.__init__`` takes, ``overrides`` on top, for ``super().__init__``."""
    parameters = inspect.signature(base).parameters.values()
    names = [p.name for p in parameters if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]
    return {name: arguments[name] for name in names if name in arguments} | overrides
