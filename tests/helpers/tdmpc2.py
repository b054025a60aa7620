"""What the TD-MPC2 tests share: tiny network sizes and the host's weighted world-model loss."""

import torch as th

from sb3_ef.tdmpc2 import TDMPC2EF

TINY_POLICY = {
    "num_channels": 4,
    "mlp_dim": 32,
    "num_q": 2,
    "planner_kwargs": {"iterations": 2, "num_samples": 16, "num_elites": 4, "num_pi_trajs": 2},
}
TINY_EF_POLICY = {**TINY_POLICY, "agent_dim": 16, "ef_kwargs": {"rollout_hidden_dims": (32,), "decoder_channels": 8}}


def tiny_policy(algorithm: type) -> dict:
    """The tiny policy arguments of TDMPC2 or (with EF's sizes) TDMPC2EF."""
    return TINY_EF_POLICY if issubclass(algorithm, TDMPC2EF) else TINY_POLICY


def host_loss(model, losses: dict[str, th.Tensor]) -> th.Tensor:
    """TD-MPC2's world-model loss (without EF) from the unweighted losses of ``model.losses``."""
    return (
        model.consistency_coef * losses["consistency_loss"]
        + model.reward_coef * losses["reward_loss"]
        + model.value_coef * losses["value_loss"]
    )
