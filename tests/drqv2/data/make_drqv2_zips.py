"""Writes DrQv2EF and DrQv2 models (and a DrQv2EF checkpoint) with the expected values a test compares after
loading them, with the DrQ-v2 of the sb3-ef it runs under.

The committed files were written by sb3-ef 0.1.0 (EF's weights inside the policy's, in the critic optimiser's only
parameter group) so that tests/ef/test_legacy_hosts.py checks that files users saved with it still load (after
`sb3-ef upgrade`):

    cd <an sb3-ef 0.1.0 checkout> && PYTHONPATH=. python <this file> <output folder>

The networks are tiny (one frame of 32x32 pixels, 16x16 without EF) and train with plain SGD, which keeps no state
per parameter: with DrQ-v2's fixed 32-filter encoder, Adam's state would take each file over 300 KB. (The TD-MPC2
files, written by tests/tdmpc2/data/make_tdmpc2_zips.py, carry Adam's state.)
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch as th

from sb3_ef.common.checkpoints import ResumableCheckpointCallback, latest_checkpoint, load_checkpoint
from sb3_ef.drqv2 import DrQv2, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv

POLICY = {"net_arch": [16], "trunk_dim": 8, "optimizer_class": th.optim.SGD}
EF_POLICY = {
    **POLICY,
    "features_dim": 24,
    "agent_dim": 8,
    "ef_kwargs": {"rollout_hidden_dims": [8], "decoder_channels": 4},
}
ARGUMENTS = {
    "learning_rate": 1e-3,
    "buffer_size": 30,
    "learning_starts": 8,
    "batch_size": 4,
    "train_freq": 1,
    "seed": 0,
}
EF_ARGUMENTS = {"ef_horizon": 2, "babbling_steps": 4}


SIZES = {DrQv2EF: 32, DrQv2: 16}
CHECKPOINT_STEP = 10


def toy_env(size: int) -> ToyAgentEnv:
    return ToyAgentEnv(size=size, frame_stack=1, max_episode_steps=10)


def observations(size: int) -> np.ndarray:
    return np.stack([toy_env(size).reset(seed=seed)[0] for seed in range(3)])


def expected(model) -> dict[str, np.ndarray]:
    """The policy's weights (``ef/`` for EF's, ``host/`` for the others), each parameter's optimiser state
    (``state/<parameter>/<key>``) and the deterministic actions on :func:`observations`."""
    values = {}
    for name, value in model.policy.state_dict().items():
        values[f"ef/{name[3:]}" if name.startswith("ef.") else f"host/{name}"] = value.cpu().numpy()
    optimizers = (model.critic.optimizer, model.actor.optimizer)
    for name, parameter in model.policy.named_parameters():
        for optimizer in optimizers:
            for key, state in optimizer.state.get(parameter, {}).items():
                values[f"state/{name}/{key}"] = th.as_tensor(state).cpu().numpy()
    values["actions"] = model.predict(observations(SIZES[type(model)]), deterministic=True)[0]
    return values


def main(folder: Path) -> None:
    for algorithm, policy, extra in ((DrQv2EF, EF_POLICY, EF_ARGUMENTS), (DrQv2, POLICY, {})):
        model = algorithm("CnnPolicy", toy_env(SIZES[algorithm]), policy_kwargs=policy, **ARGUMENTS, **extra)
        name = algorithm.__name__.lower()
        checkpoints = ResumableCheckpointCallback(CHECKPOINT_STEP, str(folder / f"{name}_checkpoint"), keep=1)
        model.learn(20, callback=checkpoints if algorithm is DrQv2EF else None)  # updates and EF steps
        model.save(folder / f"{name}_0.1.0.zip")
        np.savez_compressed(folder / f"{name}_0.1.0_expected.npz", **expected(model))
    resumed = load_checkpoint(DrQv2EF, latest_checkpoint(folder / "drqv2ef_checkpoint"), toy_env(SIZES[DrQv2EF]))
    resumed.learn(6, reset_num_timesteps=False)
    actions = resumed.predict(observations(SIZES[DrQv2EF]), deterministic=True)[0]
    np.savez_compressed(folder / "drqv2ef_checkpoint_resumed.npz", actions=actions)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
