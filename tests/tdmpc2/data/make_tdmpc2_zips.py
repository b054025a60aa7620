"""Writes TDMPC2EF and TDMPC2 models (and a TDMPC2EF checkpoint) with the expected values a test compares after
loading them, with the TD-MPC2 of the sb3-ef it runs under.

The committed files were written by sb3-ef 0.1.0 (EF's weights inside the policy's, EF's parameter group of the
world-model optimiser named ``ef``, the planner's horizon and discount in the saved ``policy_kwargs``) so that
tests/ef/test_legacy_hosts.py checks that files users saved with it still load (after `sb3-ef upgrade`):

    cd <an sb3-ef 0.1.0 checkout> && PYTHONPATH=. python <this file> <output folder>

Tiny networks on one 64x64 frame, trained with TD-MPC2's default Adam (its state is saved with the model).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch as th

from sb3_ef.common.checkpoints import ResumableCheckpointCallback, latest_checkpoint, load_checkpoint
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2, TDMPC2EF

POLICY = {
    "num_channels": 2,
    "mlp_dim": 8,
    "num_q": 2,
    "num_bins": 5,
    "planner_kwargs": {"iterations": 2, "num_samples": 16, "num_elites": 4, "num_pi_trajs": 2},
}
EF_POLICY = {**POLICY, "agent_dim": 16, "ef_kwargs": {"rollout_hidden_dims": [8], "decoder_channels": 2}}
ARGUMENTS = {"buffer_size": 12, "learning_starts": 8, "batch_size": 4, "horizon": 2, "seed": 0}
EF_ARGUMENTS = {"ef_horizon": 2, "babbling_steps": 4}
CHECKPOINT_STEP = 10


def toy_env() -> ToyAgentEnv:
    return ToyAgentEnv(size=64, frame_stack=1, max_episode_steps=10)


def observations() -> np.ndarray:
    return np.stack([toy_env().reset(seed=seed)[0] for seed in range(3)])


def deterministic_actions(model) -> np.ndarray:
    """Planned actions on :func:`observations` from a zero warm start (every env starting an episode), the
    planner's draws seeded with 0 (what a deterministic ``predict`` of later versions does)."""
    th.manual_seed(0)
    return model.predict(observations(), episode_start=np.ones(3, dtype=bool), deterministic=True)[0]


def expected(model) -> dict[str, np.ndarray]:
    """The policy's weights (``ef/`` for EF's, ``host/`` for the others), each parameter's optimiser state
    (``state/<parameter>/<key>``) and the deterministic actions."""
    values = {}
    for name, value in model.policy.state_dict().items():
        values[f"ef/{name[3:]}" if name.startswith("ef.") else f"host/{name}"] = value.cpu().numpy()
    optimizers = (model.policy.optimizer, model.policy.pi_optimizer)
    for name, parameter in model.policy.named_parameters():
        for optimizer in optimizers:
            for key, state in optimizer.state.get(parameter, {}).items():
                values[f"state/{name}/{key}"] = th.as_tensor(state).cpu().numpy()
    values["actions"] = deterministic_actions(model)
    return values


def main(folder: Path) -> None:
    for algorithm, policy, extra in ((TDMPC2EF, EF_POLICY, EF_ARGUMENTS), (TDMPC2, POLICY, {})):
        model = algorithm("CnnPolicy", toy_env(), policy_kwargs=policy, **ARGUMENTS, **extra)
        name = algorithm.__name__.lower()
        checkpoints = ResumableCheckpointCallback(CHECKPOINT_STEP, str(folder / f"{name}_checkpoint"), keep=1)
        model.learn(20, callback=checkpoints if algorithm is TDMPC2EF else None)  # updates and EF steps
        model.save(folder / f"{name}_0.1.0.zip")
        np.savez_compressed(folder / f"{name}_0.1.0_expected.npz", **expected(model))
    resumed = load_checkpoint(TDMPC2EF, latest_checkpoint(folder / "tdmpc2ef_checkpoint"), toy_env())
    resumed.learn(6, reset_num_timesteps=False)
    np.savez_compressed(folder / "tdmpc2ef_checkpoint_resumed.npz", actions=deterministic_actions(resumed))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
