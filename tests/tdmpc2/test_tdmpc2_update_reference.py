"""TDMPC2 against TD-MPC2's update (nicklashansen/tdmpc2), transcribed in tests/helpers/tdmpc2_reference.py
independently of sb3-ef's code and given sb3-ef's initial weights: three updates side by side on fixed batches, every
loss and parameter to float rounding; and the planner's value estimate of given action sequences.

The augmented window is taken from sb3-ef's update, and the reference continues from the random state the
augmentation left, so that both draw the same policy noise and the same pairs of Q heads. Dropout is off (the
authors' vectorised ensemble draws its masks in another order than a loop over the heads).
"""

from __future__ import annotations

from typing import Any

import torch as th

from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.tdmpc2 import TDMPC2
from tests.helpers.references import assert_parameters_close
from tests.helpers.tdmpc2_reference import RefTDMPC2, reference_of

BATCH = 8
# Constants away from the defaults, so that a swapped one shows.
LR, TAU, RHO, GAMMA, ENTROPY = 2e-3, 0.3, 0.7, 0.9, 0.05
# Adam divides by the root of the squared gradient: a gradient at rounding level moves a weight by up to LR.
ADAM_ROUNDING = LR / 20
POLICY = {
    "num_channels": 4, "mlp_dim": 32, "num_q": 3, "dropout": 0.0,
    "planner_kwargs": {"iterations": 2, "num_samples": 16, "num_elites": 4, "num_pi_trajs": 2},
}  # fmt: skip


def make_model() -> TDMPC2:
    model = TDMPC2(
        "CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=500), learning_rate=LR, tau=TAU, rho=RHO, gamma=GAMMA,
        entropy_coef=ENTROPY, max_grad_norm=0.5, batch_size=BATCH, buffer_size=300, learning_starts=100, seed=0,
        device="cpu", policy_kwargs=POLICY,
    )  # fmt: skip
    model.learn(60)  # random actions in one episode: every window lies inside it
    return model


def pairs(model: TDMPC2, reference: RefTDMPC2) -> dict[str, tuple[th.Tensor, th.Tensor]]:
    """sb3-ef's parameters beside the reference's (the Q heads' beside their stacked rows)."""
    world_model = model.world_model
    modules = {
        "encoder": (world_model.encoder, reference._encoder),
        "dynamics": (world_model.dynamics, reference._dynamics),
        "reward": (world_model.reward_head, reference._reward),
        "pi": (world_model.pi_head, reference._pi),
    }
    found = {
        f"{name}.{index}": (mine, theirs)
        for name, (ours, ref) in modules.items()
        for index, (mine, theirs) in enumerate(zip(ours.parameters(), ref.parameters(), strict=True))
    }
    for name, heads, stacked in (
        ("q", world_model.q_heads, list(reference._Qs.params)),
        ("target_q", world_model.target_q_heads, reference._target_Qs_params),
    ):
        for head_index, head in enumerate(heads):
            for index, (mine, theirs) in enumerate(zip(head.parameters(), stacked, strict=True)):
                found[f"{name}{head_index}.{index}"] = (mine, theirs[head_index])
    return found


def recorded_update(model: TDMPC2, batch: Any) -> tuple[dict[str, th.Tensor], Any, th.Tensor]:
    """sb3-ef's update of ``batch``, with the augmented window it drew and the random state the augmentation left."""
    seen: dict[str, Any] = {}
    losses = model._world_model_losses

    def recorded(sequence: Any) -> Any:
        seen["sequence"], seen["state"] = sequence, th.get_rng_state()
        return losses(sequence)

    model._world_model_losses = recorded  # type: ignore[method-assign]
    try:
        logs = model._update(batch)
    finally:
        del model._world_model_losses
    return logs, seen["sequence"], seen["state"]


def test_three_updates_match_the_authors_update_to_float_rounding():
    model = make_model()
    reference = reference_of(model)
    for name, (ours, theirs) in pairs(model, reference).items():
        assert th.equal(ours, theirs), name
    model.policy.set_training_mode(True)
    for update in range(3):
        batch = model.replay_buffer.sample(BATCH)
        th.manual_seed(100 + update)
        logs, sequence, state = recorded_update(model, batch)
        assert bool(sequence.valid.all())
        th.set_rng_state(state)
        observations = th.cat([sequence.first[None], sequence.following])
        expected = reference.update(observations, sequence.actions, sequence.rewards.unsqueeze(-1))
        for name, value in expected.items():
            th.testing.assert_close(logs[name], value, msg=lambda m, where=f"{name} at {update}": f"{where}: {m}")
        th.testing.assert_close(model.policy.q_scale, reference.scale[0])
        assert_parameters_close(pairs(model, reference), ADAM_ROUNDING, f"after {update}")


def test_the_planners_value_estimate_is_the_authors():
    model = make_model()
    model.policy.set_training_mode(False)
    reference = reference_of(model)
    z = model.encode(model.replay_buffer.sample(BATCH).observations)
    actions = th.rand(BATCH, model.horizon, 2) * 2 - 1
    th.manual_seed(5)
    ours = model.policy.planner.estimate_value(model.world_model, z, actions)
    th.manual_seed(5)
    theirs = reference.estimate_value(z, actions.transpose(0, 1))
    th.testing.assert_close(ours, theirs.squeeze(1))
    action = reference.plan(model.replay_buffer.sample(1).observations)
    assert action.shape == (2,) and bool((action.abs() <= 1).all())
