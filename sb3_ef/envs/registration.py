"""Gymnasium registration of the pixel environments (cheap: entry-point strings, no MuJoCo import).

Every name of :data:`sb3_ef.envs.tasks.ENV_NAMES` is registered as ``<name>-v0``, so
``gym.make("dmc/cartpole-swingup-v0", size=64)`` works after ``import sb3_ef``.
"""

import gymnasium as gym

from sb3_ef.envs.tasks import ENV_NAMES

_ENTRY_POINT = "sb3_ef.envs.factory:make_env"


def register_envs() -> None:
    """Register every pixel environment with gymnasium; calling it again changes nothing."""
    for name in ENV_NAMES:
        env_id = f"{name}-v0"
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=_ENTRY_POINT, kwargs={"name": name})
