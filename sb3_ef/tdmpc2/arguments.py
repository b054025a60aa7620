"""TD-MPC2's argument checks, and the episode length from which its ``None`` defaults are derived."""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.common.env_checks import episode_steps

#: Set by the algorithm itself, so they cannot come through ``policy_kwargs``.
ALGORITHM_POLICY_KWARGS = ("horizon", "gamma")


def check_arguments(horizon: int, policy_kwargs: dict[str, Any] | None) -> None:
    """Refuse a bad ``horizon`` and ``policy_kwargs`` holding the algorithm's own arguments."""
    if not isinstance(horizon, int) or horizon < 1:
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    reserved = sorted(set(policy_kwargs or {}) & set(ALGORITHM_POLICY_KWARGS))
    if reserved:
        raise ValueError(f"Pass {reserved} to the algorithm, not in policy_kwargs (they are set from its arguments)")


def known_episode_steps(env: VecEnv | None, argument: str) -> int:
    """The episode length ``argument=None`` is derived from; raise naming ``argument`` when it is unknown."""
    steps = None if env is None else episode_steps(env)
    if steps is None:
        raise ValueError(
            f"{argument}=None derives its value from the episode length, which this env does not expose "
            f"(no spec.max_episode_steps, TimeLimit, episode_length or max_episode_steps): pass {argument}"
        )
    return steps
