"""Warm start: a pretrained encoder + EF move exactly into DrQv2EF / TDMPC2EF, and mismatches are named."""

from __future__ import annotations

import pytest
import torch as th

from sb3_ef import TDMPC2EF, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.offline.model import OfflineEF, OfflineEFConfig
from sb3_ef.offline.pretrain import MODEL
from sb3_ef.offline.warm_start import load_ef
from tests.helpers.offline import square_episode, tiny_pretrain

EF_KWARGS = {"rollout_hidden_dims": (16,), "decoder_channels": 8}


def drqv2_ef(size: int = 32) -> DrQv2EF:
    policy_kwargs = {"net_arch": [16], "trunk_dim": 8, "features_dim": 64, "agent_dim": 8, "ef_kwargs": EF_KWARGS}
    return DrQv2EF("CnnPolicy", ToyAgentEnv(size=size), buffer_size=200, policy_kwargs=policy_kwargs, babbling_steps=0)


def tdmpc2_ef() -> TDMPC2EF:
    policy_kwargs = {"num_channels": 4, "mlp_dim": 16, "num_q": 2, "agent_dim": 16, "ef_kwargs": EF_KWARGS}
    return TDMPC2EF("CnnPolicy", ToyAgentEnv(size=64), buffer_size=200, policy_kwargs=policy_kwargs, babbling_steps=0)


def assert_same_weights(source: th.nn.Module, target: th.nn.Module) -> None:
    source_state, target_state = source.state_dict(), target.state_dict()
    assert source_state.keys() == target_state.keys()
    for key, value in source_state.items():
        assert th.equal(value, target_state[key]), key


def test_drqv2_ef_starts_from_a_pretrain_run_with_exactly_its_weights(tmp_path):
    episodes = [square_episode(steps=14, size=32, seed=seed) for seed in range(3)]
    tiny_pretrain(episodes, tmp_path, ef_kwargs=EF_KWARGS)
    model = drqv2_ef()
    critic_before = {k: v.clone() for k, v in model.policy.critic.state_dict().items()}
    assert load_ef(model, tmp_path / MODEL) is model
    source = th.load(tmp_path / MODEL, weights_only=False)["state_dict"]
    for key, value in model.policy.encoder.state_dict().items():
        assert th.equal(value, source[f"encoder.net.{key}"]), key
    for key, value in model.ef.state_dict().items():
        assert th.equal(value, source[f"ef.{key}"]), key
    assert all(th.equal(v, critic_before[k]) for k, v in model.policy.critic.state_dict().items())


def test_latent_ef_target_restarts_from_the_warm_started_encoder(tmp_path):
    """Latent EF's momentum target holds the copied encoder and projection, not the random ones it was built from."""
    latent = {**EF_KWARGS, "target": "latent"}
    episodes = [square_episode(steps=14, size=32, seed=seed) for seed in range(3)]
    tiny_pretrain(episodes, tmp_path, ef_kwargs=latent)
    policy_kwargs = {"net_arch": [16], "trunk_dim": 8, "features_dim": 64, "agent_dim": 8, "ef_kwargs": latent}
    model = DrQv2EF("CnnPolicy", ToyAgentEnv(size=32), buffer_size=200, policy_kwargs=policy_kwargs, babbling_steps=0)
    target = model.auxiliary.target_encoder
    built_with = {key: value.clone() for key, value in target.encoder.state_dict().items()}
    load_ef(model, tmp_path / MODEL)
    assert any(not th.equal(value, built_with[key]) for key, value in model.policy.encoder.state_dict().items())
    assert_same_weights(model.policy.encoder, target.encoder)
    assert_same_weights(model.ef.head.projection, target.projection)


def test_tdmpc2_ef_takes_the_world_model_encoder_and_ef():
    source = OfflineEF(OfflineEFConfig("tdmpc2", (3, 64, 64), 2, 3, 5, 16, {"num_channels": 4}, EF_KWARGS))
    with th.no_grad():
        for parameter in source.parameters():
            parameter.add_(th.randn_like(parameter))  # differ from any fresh initialisation
    model = load_ef(tdmpc2_ef(), source)
    assert_same_weights(source.encoder.net, model.policy.world_model.encoder)
    assert_same_weights(source.ef, model.ef)


@pytest.mark.parametrize(
    "config, match",
    [
        (OfflineEFConfig("tdmpc2", (3, 64, 64), 2, 3, 5, 8, {"num_channels": 4}, EF_KWARGS), "needs 'drqv2'"),
        (OfflineEFConfig("drqv2", (3, 32, 32), 2, 2, 5, 8, {"features_dim": 64}, EF_KWARGS), "pretrained 2, RL model"),
        (OfflineEFConfig("drqv2", (3, 32, 32), 2, 3, 5, 16, {"features_dim": 64}, EF_KWARGS), r"pretrained \(16, 18\)"),
        (OfflineEFConfig("drqv2", (3, 32, 32), 2, 3, 5, 8, {"features_dim": 96}, EF_KWARGS), "encoder projection"),
    ],
)
def test_mismatched_architectures_are_refused_with_the_difference(config, match):
    with pytest.raises(ValueError, match=match):
        load_ef(drqv2_ef(), OfflineEF(config))
