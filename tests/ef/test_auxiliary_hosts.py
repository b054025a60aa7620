"""The auxiliary-loss interface as hosts use it: a plain host carries a loss a subclass supplies, the EF variants
extend the plain algorithms, and ``load`` refuses a file another algorithm saved."""

from __future__ import annotations

import io

import pytest
import torch as th
from stable_baselines3 import SAC
from torch import nn

from sb3_ef import TDMPC2, TDMPC2EF, DrQv2, DrQv2EF
from sb3_ef.common.augmentation import random_shift
from sb3_ef.drqv2.policies import DrQv2Encoder, DrQv2Policy
from sb3_ef.ef import AuxiliaryLoss
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.sb3_hosts import AuxiliaryStepMixin
from sb3_ef.tdmpc2.policies import TDMPC2Policy

DRQV2 = {"policy_kwargs": {"net_arch": [8], "trunk_dim": 8, "features_dim": 16}}
DRQV2_EF = {"policy_kwargs": {**DRQV2["policy_kwargs"], "agent_dim": 4}, "ef_horizon": 2, "babbling_steps": 0}
TDMPC2_POLICY = {
    "num_channels": 4, "mlp_dim": 16, "num_q": 2,
    "planner_kwargs": {"iterations": 1, "num_samples": 8, "num_elites": 2, "num_pi_trajs": 1},
}  # fmt: skip


class BrightnessLoss(AuxiliaryLoss):
    """A small real auxiliary loss: predict the mean brightness of the newest frame from the features, weighted by
    ``weight``; counts the updates it has followed (a buffer, so that it is saved with the policy)."""

    def __init__(self, feature_dim: int, weight: float = 0.5):
        super().__init__()
        self.head = nn.Linear(feature_dim, 1)
        self.weight = weight
        self.register_buffer("updates", th.zeros((), dtype=th.long))

    def prepare(self, batch, pad, generator=None):
        (observations,) = random_shift(batch.observations, pad=pad)
        return observations, observations[:, -3:].float().mean(dim=(1, 2, 3)) / 255.0

    def forward(self, features, targets):
        loss = (self.head(features).squeeze(1) - targets).pow(2).mean()
        return self.weight * loss, {"brightness_loss": loss.detach()}

    def after_update(self, encoder: nn.Module) -> None:
        self.updates += 1


class BrightDrQv2(DrQv2):
    def _build_auxiliary(self) -> BrightnessLoss:
        return BrightnessLoss(self.policy.encoder.features_dim)


class BrightTDMPC2(TDMPC2):
    def _build_auxiliary(self) -> BrightnessLoss:
        return BrightnessLoss(self.policy.world_model.latent_dim)


class BrightSAC(AuxiliaryStepMixin, SAC):
    def _build_auxiliary(self) -> BrightnessLoss:
        return BrightnessLoss(self.critic.features_extractor.features_dim)


def make(algorithm, **kwargs):
    common = {"buffer_size": 100, "learning_starts": 8, "batch_size": 4, "seed": 0}
    if issubclass(algorithm, TDMPC2):
        extra = {"policy_kwargs": TDMPC2_POLICY, "seed_burst": False}
        if algorithm is TDMPC2EF:
            extra = {"policy_kwargs": {**TDMPC2_POLICY, "agent_dim": 16}, "ef_horizon": 2, "babbling_steps": 0}
        return algorithm("CnnPolicy", ToyAgentEnv(size=64, max_episode_steps=10), **common, **extra, **kwargs)
    if issubclass(algorithm, SAC):
        policy = {"net_arch": [8], "normalize_images": False, "features_extractor_class": DrQv2Encoder,
                  "features_extractor_kwargs": {"features_dim": 16}}  # fmt: skip
        return algorithm("CnnPolicy", ToyAgentEnv(size=32, max_episode_steps=10), policy_kwargs=policy, **common)
    extra = DRQV2_EF if algorithm is DrQv2EF else DRQV2
    return algorithm("CnnPolicy", ToyAgentEnv(size=32, max_episode_steps=10), **common, **extra, **kwargs)


def optimised(optimizer: th.optim.Optimizer) -> set[int]:
    return {id(param) for group in optimizer.param_groups for param in group["params"]}


@pytest.mark.parametrize("algorithm", [BrightDrQv2, BrightTDMPC2, BrightSAC])
def test_a_plain_host_trains_the_auxiliary_loss_its_subclass_supplies(algorithm, tmp_path):
    model = make(algorithm)
    auxiliary = model.auxiliary
    assert isinstance(auxiliary, BrightnessLoss) and not hasattr(model, "ef")
    # On the policy for DrQ-v2 and TD-MPC2; on the algorithm for SB3's hosts, whose policy stays SB3's own.
    kept = model.auxiliary_module if algorithm is BrightSAC else model.policy.auxiliary
    assert kept is auxiliary
    optimizer = {
        BrightDrQv2: lambda: model.critic.optimizer,
        BrightTDMPC2: lambda: model.policy.optimizer,
        BrightSAC: lambda: model.auxiliary_optimizer,
    }[algorithm]()
    assert {id(param) for param in auxiliary.parameters()} <= optimised(optimizer)
    head = auxiliary.head.weight.detach().clone()
    model.learn(12)
    assert "train/brightness_loss" in model.logger.name_to_value
    assert not th.equal(auxiliary.head.weight, head)  # the loss trained its module
    assert int(auxiliary.updates) == model._n_updates > 0  # after_update followed every update

    model.save(tmp_path / "model")
    loaded = algorithm.load(tmp_path / "model")
    assert th.equal(loaded.auxiliary.head.weight, auxiliary.head.weight) and int(loaded.auxiliary.updates) > 0


@pytest.mark.parametrize(("plain", "variant"), [(DrQv2, DrQv2EF), (TDMPC2, TDMPC2EF)])
def test_the_ef_variant_extends_the_plain_algorithm_and_not_the_reverse(plain, variant):
    assert issubclass(variant, plain) and not issubclass(plain, variant)
    assert not isinstance(make(plain), variant) and isinstance(make(variant), plain)


@pytest.mark.parametrize(
    ("saved", "loader"), [(DrQv2EF, DrQv2), (DrQv2, DrQv2EF), (DrQv2EF, TDMPC2EF), (TDMPC2, TDMPC2EF)]
)
def test_load_refuses_a_file_saved_by_another_algorithm(saved, loader, tmp_path):
    make(saved).save(tmp_path / "model.zip")
    message = rf"Cannot load .*model.zip as {loader.__name__}: it was saved by {saved.__name__}, use {saved.__name__}"
    with pytest.raises(ValueError, match=message):
        loader.load(tmp_path / "model.zip")
    with open(tmp_path / "model.zip", "rb") as file:  # also from an open file, which is left where it was
        stream = io.BytesIO(file.read())
    with pytest.raises(ValueError, match=f"saved by {saved.__name__}"):
        loader.load(stream)
    assert stream.tell() == 0
    assert type(saved.load(stream)) is saved


def test_setting_beta_reweights_the_ef_loss_and_is_saved(tmp_path):
    model = make(DrQv2EF)
    model.learn(10)
    model.beta = 0.25  # e.g. a schedule, or an intervention on a loaded checkpoint
    observations, targets = model._augment_observations(model.replay_buffer.sample(4), pad=4)
    weighted, logs = model.auxiliary(model.encode(observations), targets)
    th.testing.assert_close(weighted, 0.25 * logs["ef_loss"])
    model.save(tmp_path / "model")
    loaded = DrQv2EF.load(tmp_path / "model")
    assert loaded.beta == loaded.auxiliary.beta == 0.25


@pytest.mark.parametrize(("variant", "plain_policy"), [(DrQv2EF, DrQv2Policy), (TDMPC2EF, TDMPC2Policy)])
def test_an_ef_variant_refuses_the_plain_policy(variant, plain_policy):
    size, policy_kwargs = (64, TDMPC2_POLICY) if variant is TDMPC2EF else (32, DRQV2["policy_kwargs"])
    message = rf"{variant.__name__} needs a {variant.__name__}Policy .*got {plain_policy.__name__}"
    env = ToyAgentEnv(size=size, max_episode_steps=10)
    with pytest.raises(TypeError, match=message):
        variant(plain_policy, env, buffer_size=100, policy_kwargs=policy_kwargs)
