"""Small sizes for the zoo tests: hyperparameter overrides that make any zoo_configs entry cheap to build and run.

The same overrides are given as dicts (for ExperimentManager) and as rl-zoo3 command-line strings.
"""

from __future__ import annotations

from typing import Any

from sb3_ef.zoo.config import ZOO_ALGORITHMS
from tests.helpers.tdmpc2 import TINY_POLICY

#: Per algorithm: frames of this size (TD-MPC2's encoder takes 64x64 only; CURL's are cropped to 32x32), short
#: episodes, fast rendering.
_SIZES = {"tdmpc2_ef": 64, "tdmpc2": 64, "curl": 40}
ENV_KWARGS: dict[str, dict[str, Any]] = {
    algo: {"size": _SIZES.get(algo, 32), "fast_render": True, "episode_length": 40} for algo in ZOO_ALGORITHMS
}
ENV_KWARGS["sear"]["agent_masks"] = True  # rl-zoo3's --env-kwargs replace the entry's

_DRQV2_POLICY = {"net_arch": [32], "trunk_dim": 16}
_TDMPC2_POLICY = {**TINY_POLICY, "num_bins": 11}
#: SB3's NatureCNN needs 36x36 frames or more: DrQ-v2's encoder (it scales the pixels itself) for the 32x32 ones.
_SB3_POLICY = (
    "dict(net_arch=[16], normalize_images=False, features_extractor_class=DrQv2Encoder, "
    "features_extractor_kwargs=dict(features_dim=32))"
)
_EF_POLICY = {"agent_dim": 8, "ef_kwargs": {"decoder_channels": 8, "rollout_hidden_dims": (16,)}}
_EF_ALGO = {"ef_horizon": 3, "babbling_steps": 20}
_ON_POLICY = {"agent_dim": 8, "ef_kwargs": _EF_POLICY["ef_kwargs"], **_EF_ALGO, "policy_kwargs": _SB3_POLICY}

#: Per algorithm: hyperparameter overrides (buffer, batch, warm-up, network sizes; PPO-EF's and A2C-EF's rollouts).
HYPERPARAMS: dict[str, dict[str, Any]] = {
    "drqv2_ef": {
        "buffer_size": 4000,
        "batch_size": 8,
        "learning_starts": 40,
        **_EF_ALGO,
        "policy_kwargs": {**_DRQV2_POLICY, "features_dim": 64, **_EF_POLICY},
    },
    "drqv2": {"buffer_size": 4000, "batch_size": 8, "learning_starts": 40, "policy_kwargs": _DRQV2_POLICY},
    "tdmpc2_ef": {
        "buffer_size": 4000,
        "batch_size": 8,
        "learning_starts": 40,
        **_EF_ALGO,
        "policy_kwargs": {**_TDMPC2_POLICY, **_EF_POLICY},
    },
    "tdmpc2": {"buffer_size": 4000, "batch_size": 8, "learning_starts": 40, "policy_kwargs": _TDMPC2_POLICY},
    **{
        algo: {
            "buffer_size": 4000,
            "batch_size": 8,
            "learning_starts": 40,
            "agent_dim": 8,
            "ef_kwargs": _EF_POLICY["ef_kwargs"],
            **_EF_ALGO,
            "policy_kwargs": _SB3_POLICY,
        }
        for algo in ("sac_ef", "td3_ef", "tqc_ef")
    },
    "ppo_ef": {"n_steps": 20, "batch_size": 20, "n_epochs": 1, **_ON_POLICY},
    "a2c_ef": {"n_steps": 20, **_ON_POLICY},
    "sear": {
        "buffer_size": 4000,
        "batch_size": 8,
        "learning_starts": 40,
        "policy_kwargs": {**_DRQV2_POLICY, "features_dim": 64},
    },
    "curl": {
        "buffer_size": 4000,
        "batch_size": 8,
        "learning_starts": 40,
        "crop_size": 32,
        "features_dim": 16,
        "policy_kwargs": {"net_arch": [32]},
    },
}


def cli_pairs(values: dict[str, Any]) -> list[str]:
    """``{"a": 1}`` -> ``["a:1"]`` in rl-zoo3's ``key:value`` syntax (values as Python literals)."""
    return [f"{key}:{value!r}" for key, value in values.items()]


def train_args(algo: str, env_id: str, log_folder: str, n_timesteps: int) -> list[str]:
    """rl-zoo3 train arguments for a short, small, unevaluated run."""
    return [
        "--algo", algo, "--env", env_id, "-n", str(n_timesteps), "-f", log_folder, "--seed", "0",
        "--eval-freq", "-1", "--num-threads", "1", "--verbose", "0",
        "--env-kwargs", *cli_pairs(ENV_KWARGS[algo]),
        "--hyperparams", *cli_pairs(HYPERPARAMS[algo]),
    ]  # fmt: skip
