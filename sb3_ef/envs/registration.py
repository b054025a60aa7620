"""Gymnasium registration (no MuJoCo import) of every env name as ``<name>-v0`` and of the toy world; the Atari ids
of ``ale-py`` (the ``atari`` extra) where a caller names one."""

import contextlib

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


def register_atari(env_id: str) -> None:
    """Register ``ale-py``'s Atari ids with gymnasium, as rl-zoo3's ``import_envs`` does, unless ``env_id`` is
    registered already (nothing when ``ale-py`` is not installed)."""
    if env_id not in gym.registry:
        with contextlib.suppress(ImportError):
            import ale_py  # noqa: F401  (importing it registers the ids)


def is_atari(env_id: str) -> bool:
    """Whether ``env_id`` is an Arcade Learning Environment game (rl-zoo3 gives it a config's ``atari`` entry)."""
    register_atari(env_id)
    spec = gym.registry.get(env_id)
    return spec is not None and "AtariEnv" in str(spec.entry_point)
