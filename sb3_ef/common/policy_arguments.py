"""Policy arguments an algorithm derives itself, given to its policy without entering the user's ``policy_kwargs``."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any


@contextmanager
def policy_built_with(model: Any, defaults: dict[str, Any] | None = None, **derived: Any) -> Iterator[None]:
    """While the block runs (SB3's ``_setup_model`` builds the policy from ``model.policy_kwargs``), the policy
    gets ``defaults`` unless the user's kwargs set them, and ``derived`` always; ``model.policy_kwargs`` is the
    user's own again afterwards. So the saved kwargs are those the user passed, and ``Algorithm.load(path,
    policy_kwargs=<the constructor's own>)`` passes SB3's check that they equal the stored ones."""
    given = model.policy_kwargs
    model.policy_kwargs = {**(defaults or {}), **given, **derived}
    try:
        yield
    finally:
        model.policy_kwargs = given
