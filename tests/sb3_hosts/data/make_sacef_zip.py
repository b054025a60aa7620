"""Writes sacef_0.1.0.zip and its expected EF weights and actions with the SAC-EF of the sb3-ef it runs under.

The committed files were written by sb3-ef 0.1.0 (EF's weights saved inside the policy's) so that
tests/sb3_hosts/test_contract_sb3_hosts.py checks that SAC-EF models users saved with it still load:

    cd <an sb3-ef 0.1.0 checkout> && PYTHONPATH=. python <this file> <output folder>
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sb3_ef import SACEF
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv

POLICY = {
    "net_arch": [16],
    "normalize_images": False,
    "features_extractor_class": DrQv2Encoder,
    "features_extractor_kwargs": {"features_dim": 16, "n_filters": 4},
}
EF = {"ef_horizon": 2, "agent_dim": 4, "ef_kwargs": {"rollout_hidden_dims": [8], "decoder_channels": 4}}


def observations() -> np.ndarray:
    return np.stack([ToyAgentEnv(size=32, max_episode_steps=20).reset(seed=seed)[0] for seed in range(3)])


def main(folder: Path) -> None:
    env = ToyAgentEnv(size=32, max_episode_steps=20)
    arguments = {"buffer_size": 100, "learning_starts": 8, "batch_size": 4, "seed": 0}
    model = SACEF("CnnPolicy", env, policy_kwargs=POLICY, **arguments, **EF)
    model.learn(12)  # a few host updates and EF steps: trained weights, EF's Adam state
    model.save(folder / "sacef_0.1.0.zip")
    expected = {f"ef/{name}": value.cpu().numpy() for name, value in model.ef.state_dict().items()}
    expected["actions"] = model.predict(observations(), deterministic=True)[0]
    np.savez_compressed(folder / "sacef_0.1.0_expected.npz", **expected)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
