"""What the reference tests share: comparing a model's parameters with a reference implementation's."""

from __future__ import annotations

from collections.abc import Mapping

import torch as th


def assert_parameters_close(pairs: Mapping[str, tuple[th.Tensor, th.Tensor]], atol: float, when: str) -> None:
    """Each ``name: (ours, theirs)`` pair equal within ``atol`` (Adam's rounding) and a relative 1e-4; a failure names
    the parameter and ``when`` (``"after 2"``)."""
    for name, (ours, theirs) in pairs.items():
        th.testing.assert_close(
            ours, theirs, atol=atol, rtol=1e-4, msg=lambda m, where=f"{name} {when}": f"{where}: {m}"
        )
