"""A tiny SEAR on the toy env with agent masks, shared by the SEAR and the mask-analysis tests."""

from __future__ import annotations

from sb3_ef import SEAR
from sb3_ef.envs.toy import ToyAgentEnv

SIZE = 32
POLICY = {"features_dim": 64, "net_arch": [32], "trunk_dim": 16}


def toy_env(**kwargs) -> ToyAgentEnv:
    """The 32x32 toy env, 20-step episodes, with agent masks unless ``agent_masks=False``."""
    return ToyAgentEnv(size=SIZE, max_episode_steps=20, **{"agent_masks": True, **kwargs})


def make_sear(**kwargs) -> SEAR:
    """A small CPU SEAR on :func:`toy_env`; ``kwargs`` override its arguments."""
    arguments = {"buffer_size": 300, "learning_starts": 12, "batch_size": 8, "seed": 0, "device": "cpu"}
    arguments["policy_kwargs"] = dict(POLICY)
    return SEAR("CnnPolicy", toy_env(), **{**arguments, **kwargs})
