"""Schedules given as strings (``"linear(1.0,0.1,100000)"``), numbers or callables of the step count."""

from __future__ import annotations

import contextlib
import re
from collections.abc import Callable

StepSchedule = Callable[[int], float]

_LINEAR = re.compile(r"^\s*linear\(\s*([^,]+),\s*([^,]+),\s*([^,)]+)\s*\)\s*$")


def linear_schedule(initial: float, final: float, duration: int) -> StepSchedule:
    """Go linearly from ``initial`` to ``final`` over ``duration`` steps, then stay at ``final``."""
    if duration <= 0:
        raise ValueError(f"linear schedule duration must be positive, got {duration}")

    def schedule(step: int) -> float:
        fraction = min(max(step / duration, 0.0), 1.0)
        return initial + fraction * (final - initial)

    return schedule


def get_step_schedule(spec: float | str | StepSchedule) -> StepSchedule:
    """Turn a number, a ``"linear(initial, final, duration)"`` string or a callable into a schedule of steps."""
    if callable(spec):
        return spec
    if isinstance(spec, str) and (match := _LINEAR.match(spec)):
        initial, final, duration = (float(group) for group in match.groups())
        return linear_schedule(initial, final, int(duration))
    if isinstance(spec, (int, float, str)):
        with contextlib.suppress(ValueError):
            value = float(spec)
            return lambda _step: value
    raise ValueError(
        f"Expected a number, a callable or a string 'linear(initial, final, duration)' for a schedule, got {spec!r}"
    )
