"""The algorithms' ``compile`` option: ``False``, ``True``, a mode name or a dict of ``torch.compile`` arguments."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, TypeVar

import torch as th

CompileOption = bool | str | dict[str, Any]
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune", "max-autotune-no-cudagraphs")
_COMPILE_KWARGS = tuple(name for name in inspect.signature(th.compile).parameters if name != "model")
F = TypeVar("F", bound=Callable[..., Any])


def compile_kwargs(compile: CompileOption) -> dict[str, Any] | None:
    """The ``torch.compile`` arguments that ``compile`` stands for; ``None`` when it is ``False`` (eager)."""
    if compile is False:
        return None
    if compile is True:
        return {}
    if isinstance(compile, str) and compile in COMPILE_MODES:
        return {"mode": compile}
    if isinstance(compile, dict) and all(isinstance(key, str) and key in _COMPILE_KWARGS for key in compile):
        return dict(compile)
    raise ValueError(
        f"compile must be False, True, one of the torch.compile modes {list(COMPILE_MODES)} or a dict of "
        f"torch.compile arguments {list(_COMPILE_KWARGS)}, got {compile!r}"
    )


def maybe_compile(function: F, compile: CompileOption) -> F:
    """``function`` compiled as ``compile`` says (unchanged when it is ``False``)."""
    kwargs = compile_kwargs(compile)
    return function if kwargs is None else th.compile(function, **kwargs)  # type: ignore[return-value]
