"""Gymnasium registration (no MuJoCo import) of every env name as ``<name>-v0`` and of the toy world."""

import gymnasium as gym

from sb3_ef.envs.tasks import ENV_NAMES

_ENTRY_POINTS: dict[str, tuple[str, dict[str, str]]] = {
    **{f"{name}-v0": ("sb3_ef.envs.factory:make_env", {"name": name}) for name in ENV_NAMES},
    "toy/agent-v0": ("sb3_ef.envs.toy:ToyAgentEnv", {}),
}


def register_envs() -> None:
    """Register every pixel environment with gymnasium; calling it again changes nothing."""
    for env_id, (entry_point, kwargs) in _ENTRY_POINTS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=entry_point, kwargs=kwargs)
