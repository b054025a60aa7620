"""Babbling actions: random actions in [-1, 1] drawn component by component."""

from __future__ import annotations

import numpy as np

BABBLING_MODES = ("sign", "clamped_uniform")


def check_babbling(babbling_steps: int, mode: str) -> None:
    """Check the hosts' ``babbling_steps`` and ``babbling_mode`` (and the offline collector's mode)."""
    if babbling_steps < 0:
        raise ValueError(f"babbling_steps must be >= 0, got {babbling_steps}")
    if mode not in BABBLING_MODES:
        raise ValueError(f"babbling_mode must be one of {BABBLING_MODES}, got {mode!r}")


def babble(rng: np.random.Generator, shape: tuple[int, ...], mode: str = "sign") -> np.ndarray:
    """Float32 babbling actions in [-1, 1]: ``"sign"`` +-1, ``"clamped_uniform"`` uniform(-4, 4) clamped."""
    if mode == "sign":
        return np.where(rng.random(shape) < 0.5, -1.0, 1.0).astype(np.float32)
    return np.clip(rng.uniform(-4.0, 4.0, shape), -1.0, 1.0).astype(np.float32)
