"""Babbling actions: random actions in [-1, 1] drawn component by component; uniform ones of discrete spaces."""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

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


def babble_env_actions(rng: np.random.Generator, space: spaces.Space, n_envs: int, mode: str = "sign") -> np.ndarray:
    """``n_envs`` env actions: :func:`babble` mapped onto a Box's bounds; uniform draws of Discrete (as SB3's policies
    give them, from 0), MultiDiscrete and MultiBinary actions."""
    if isinstance(space, spaces.Box):
        scaled = babble(rng, (n_envs, *space.shape), mode)
        return (space.low + (scaled + 1.0) * (space.high - space.low) / 2.0).astype(space.dtype)
    if isinstance(space, spaces.Discrete):
        return rng.integers(space.n, size=n_envs)
    if isinstance(space, spaces.MultiDiscrete):
        return rng.integers(space.nvec, size=(n_envs, *space.nvec.shape))
    if isinstance(space, spaces.MultiBinary):
        return rng.integers(2, size=(n_envs, *space.shape))
    raise ValueError(f"Motor babbling draws Box, Discrete, MultiDiscrete or MultiBinary actions, got {space}")
