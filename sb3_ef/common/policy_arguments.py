"""Policy arguments an algorithm derives itself, given to its policy without entering the user's ``policy_kwargs``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def policy_built_with(model: Any, defaults: dict[str, Any] | None = None, **derived: Any) -> Iterator[None]:
    """Within ``_setup_model``, ``model.policy_kwargs`` adds unset ``defaults`` and ``derived``; afterwards it is the
    user's again, so saved kwargs pass SB3's check on ``load(policy_kwargs=...)``."""
    given = model.policy_kwargs
    model.policy_kwargs = {**(defaults or {}), **given, **derived}
    try:
        yield
    finally:
        model.policy_kwargs = given
