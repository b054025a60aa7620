"""PPO-EF on the toy world of the tests at several ``beta``: return after 4096 steps and the last ``aux_grad_ratio``.

python experiments/2026-12-onpolicy-ef/beta_toy.py 0.001 0.01 0.1 1
"""

from __future__ import annotations

import sys
import time

import torch as th
from stable_baselines3.common.env_util import make_vec_env

from sb3_ef import PPOEF
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from tests.helpers.learning import trained_and_random_returns

POLICY = {
    "net_arch": [64],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 64},
}


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=32, max_episode_steps=20)


def main() -> None:
    th.set_num_threads(1)
    for beta in map(float, sys.argv[1:]):
        start = time.perf_counter()
        model = PPOEF(
            "CnnPolicy", make_vec_env(toy_env, n_envs=8, seed=0), n_steps=32, batch_size=64, n_epochs=4,
            learning_rate=1e-3, policy_kwargs=POLICY, ef_horizon=3, agent_dim=8, beta=beta,
            ef_kwargs={"rollout_hidden_dims": (32,), "decoder_channels": 16}, seed=0,
        )  # fmt: skip
        model.learn(4096)
        trained, random = trained_and_random_returns(model, toy_env)
        ratio = model.logger.name_to_value["train/aux_grad_ratio"]
        print(f"beta {beta}: return {trained:.2f} (random {random:.2f}), aux_grad_ratio {ratio:.3g}, "
              f"{time.perf_counter() - start:.0f} s", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
