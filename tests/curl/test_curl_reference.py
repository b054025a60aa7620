"""CURL against the authors' update (MishaLaskin/curl, ``curl_sac.py``): a transcription of its equations written
here, independently of sb3-ef's code, given sb3-ef's initial weights, and run side by side on fixed batches.

Losses, the parameters each optimiser steps and in which order, the soft updates with their taus, and every
parameter after each of three updates (actor and targets on updates 0 and 2, not on 1) agree to float rounding.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ef import CURL
from sb3_ef.curl.curl import CURLBatch
from sb3_ef.envs.toy import ToyAgentEnv

FRAME, CROP, BATCH, FEATURES, FILTERS, HIDDEN = 40, 32, 6, 8, 8, 16
# Taus far from each other and from the defaults, so that a swapped tau or a soft update out of order shows.
TAU, ENCODER_TAU, LR, ENCODER_LR = 0.3, 0.6, 2e-3, 3e-3


# The reference, transcribed from curl_sac.py and encoder.py (PixelEncoder with output_logits=True).


class RefEncoder(nn.Module):
    def __init__(self, channels: int, feature_dim: int, num_layers: int, num_filters: int, size: int):
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(channels, num_filters, 3, stride=2)])
        for _ in range(num_layers - 1):
            self.convs.append(nn.Conv2d(num_filters, num_filters, 3, stride=1))
        out_dim = (size - 3) // 2 + 1 - 2 * (num_layers - 1)
        self.fc = nn.Linear(num_filters * out_dim * out_dim, feature_dim)
        self.ln = nn.LayerNorm(feature_dim)

    def forward(self, obs: th.Tensor, detach: bool = False) -> th.Tensor:
        conv = obs / 255.0
        for layer in self.convs:
            conv = th.relu(layer(conv))
        h = conv.view(conv.size(0), -1)
        if detach:
            h = h.detach()
        return self.ln(self.fc(h))

    def copy_conv_weights_from(self, source: RefEncoder) -> None:
        for mine, theirs in zip(self.convs, source.convs, strict=True):
            mine.weight, mine.bias = theirs.weight, theirs.bias


def mlp(inputs: int, hidden: int, outputs: int) -> nn.Sequential:
    layers = [nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, outputs)]
    return nn.Sequential(*layers)


class RefActor(nn.Module):
    def __init__(self, encoder: RefEncoder, action_dim: int, log_std_min: float = -10, log_std_max: float = 2):
        super().__init__()
        self.encoder, self.log_std_min, self.log_std_max = encoder, log_std_min, log_std_max
        self.trunk = mlp(FEATURES, HIDDEN, 2 * action_dim)

    def forward(self, obs: th.Tensor, detach_encoder: bool = False) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        mu, log_std = self.trunk(self.encoder(obs, detach=detach_encoder)).chunk(2, dim=-1)
        log_std = th.tanh(log_std)
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (log_std + 1)
        noise = th.randn_like(mu)
        pi = mu + noise * log_std.exp()
        log_pi = (-0.5 * noise.pow(2) - log_std).sum(-1, keepdim=True) - 0.5 * np.log(2 * np.pi) * noise.size(-1)
        pi = th.tanh(pi)
        log_pi = log_pi - th.log(F.relu(1 - pi.pow(2)) + 1e-6).sum(-1, keepdim=True)
        return pi, log_pi, log_std


class RefCritic(nn.Module):
    def __init__(self, encoder: RefEncoder, action_dim: int):
        super().__init__()
        self.encoder = encoder
        self.Q1, self.Q2 = mlp(FEATURES + action_dim, HIDDEN, 1), mlp(FEATURES + action_dim, HIDDEN, 1)

    def forward(self, obs: th.Tensor, action: th.Tensor, detach_encoder: bool = False) -> tuple[th.Tensor, th.Tensor]:
        obs_action = th.cat([self.encoder(obs, detach=detach_encoder), action], dim=1)
        return self.Q1(obs_action), self.Q2(obs_action)


def soft_update_params(net: nn.Module, target_net: nn.Module, tau: float) -> None:
    for param, target_param in zip(net.parameters(), target_net.parameters(), strict=True):
        target_param.data.copy_(tau * param.data + (1 - tau) * target_param.data)


class RefAgent:
    """CurlSacAgent's update, with its optimisers (train.py's betas and the temperature's lr 1e-4, beta1 0.5)."""

    def __init__(self, actor: RefActor, critic: RefCritic, target: RefCritic, log_alpha: th.Tensor, W: th.Tensor):
        self.actor, self.critic, self.critic_target = actor, critic, target
        self.log_alpha = log_alpha.requires_grad_(True)
        self.target_entropy = -2  # -|A|
        self.curl = nn.Module()
        self.curl.encoder, self.curl.encoder_target = critic.encoder, target.encoder
        self.curl.W = nn.Parameter(W)
        self.actor_optimizer = th.optim.Adam(actor.parameters(), lr=LR, betas=(0.9, 0.999))
        self.critic_optimizer = th.optim.Adam(critic.parameters(), lr=LR, betas=(0.9, 0.999))
        self.log_alpha_optimizer = th.optim.Adam([self.log_alpha], lr=1e-4, betas=(0.5, 0.999))
        self.encoder_optimizer = th.optim.Adam(critic.encoder.parameters(), lr=ENCODER_LR)
        self.cpc_optimizer = th.optim.Adam(self.curl.parameters(), lr=ENCODER_LR)

    @property
    def alpha(self) -> th.Tensor:
        return self.log_alpha.exp()

    def update(self, obs, action, reward, next_obs, not_done, obs_pos, step: int) -> dict[str, th.Tensor]:
        losses = {}
        with th.no_grad():
            policy_action, log_pi, _ = self.actor(next_obs)
            target_Q1, target_Q2 = self.critic_target(next_obs, policy_action)
            target_V = th.min(target_Q1, target_Q2) - self.alpha.detach() * log_pi
            target_Q = reward + (not_done * 0.99 * target_V)
        current_Q1, current_Q2 = self.critic(obs, action)
        losses["critic_loss"] = critic_loss = F.mse_loss(current_Q1, target_Q) + F.mse_loss(current_Q2, target_Q)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        if step % 2 == 0:  # actor_update_freq
            pi, log_pi, _ = self.actor(obs, detach_encoder=True)
            actor_Q1, actor_Q2 = self.critic(obs, pi, detach_encoder=True)
            losses["actor_loss"] = actor_loss = (self.alpha.detach() * log_pi - th.min(actor_Q1, actor_Q2)).mean()
            self.actor_optimizer.zero_grad()
            actor_loss.backward()
            self.actor_optimizer.step()
            self.log_alpha_optimizer.zero_grad()
            alpha_loss = (self.alpha * (-log_pi - self.target_entropy).detach()).mean()
            losses["ent_coef_loss"] = alpha_loss
            alpha_loss.backward()
            self.log_alpha_optimizer.step()
        if step % 2 == 0:  # critic_target_update_freq
            soft_update_params(self.critic.Q1, self.critic_target.Q1, TAU)
            soft_update_params(self.critic.Q2, self.critic_target.Q2, TAU)
            soft_update_params(self.critic.encoder, self.critic_target.encoder, ENCODER_TAU)
        z_a = self.curl.encoder(obs)
        with th.no_grad():
            z_pos = self.curl.encoder_target(obs_pos)
        logits = th.matmul(z_a, th.matmul(self.curl.W, z_pos.T))
        logits = logits - th.max(logits, 1)[0][:, None]
        losses["curl_loss"] = loss = nn.CrossEntropyLoss()(logits, th.arange(logits.shape[0]).long())
        self.encoder_optimizer.zero_grad()
        self.cpc_optimizer.zero_grad()
        loss.backward()
        self.encoder_optimizer.step()
        self.cpc_optimizer.step()
        return {name: value.detach() for name, value in losses.items()}


# sb3-ef's model, and the reference given its weights.


def make_model() -> CURL:
    return CURL(
        "CnnPolicy", ToyAgentEnv(size=FRAME, max_episode_steps=20), crop_size=CROP, features_dim=FEATURES,
        learning_rate=LR, auxiliary_learning_rate=ENCODER_LR, tau=TAU, encoder_tau=ENCODER_TAU, buffer_size=100,
        policy_kwargs={"net_arch": [HIDDEN, HIDDEN], "features_extractor_kwargs": {"n_filters": FILTERS}},
        seed=0, device="cpu",
    )  # fmt: skip


def copy_encoder(reference: RefEncoder, encoder: nn.Module) -> None:
    convs = [module for module in encoder.convnet if isinstance(module, nn.Conv2d)]
    for mine, theirs in zip(reference.convs, convs, strict=True):
        mine.load_state_dict(theirs.state_dict())
    reference.fc.load_state_dict(encoder.projection[0].state_dict())
    reference.ln.load_state_dict(encoder.projection[1].state_dict())


def copy_critic(reference: RefCritic, critic: nn.Module) -> None:
    copy_encoder(reference.encoder, critic.features_extractor)
    reference.Q1.load_state_dict(critic.qf0.state_dict())
    reference.Q2.load_state_dict(critic.qf1.state_dict())


def reference_of(model: CURL) -> RefAgent:
    def encoder() -> RefEncoder:
        return RefEncoder(9, FEATURES, 4, FILTERS, CROP)

    critic, critic_target = RefCritic(encoder(), 2), RefCritic(encoder(), 2)
    copy_critic(critic, model.critic)
    copy_critic(critic_target, model.critic_target)
    actor = RefActor(encoder(), 2)
    copy_encoder(actor.encoder, model.actor.features_extractor)
    actor.encoder.copy_conv_weights_from(critic.encoder)  # the authors tie the actor's convolutions to the critic's
    with th.no_grad():
        actor.trunk[0].load_state_dict(model.actor.latent_pi[0].state_dict())
        actor.trunk[2].load_state_dict(model.actor.latent_pi[2].state_dict())
        actor.trunk[4].weight.copy_(th.cat([model.actor.mu.weight, model.actor.log_std.weight]))
        actor.trunk[4].bias.copy_(th.cat([model.actor.mu.bias, model.actor.log_std.bias]))
    log_alpha = model.log_ent_coef.detach().clone().reshape(())
    return RefAgent(actor, critic, critic_target, log_alpha, model.auxiliary.W.detach().clone())


Pairs = dict[str, tuple[th.Tensor, th.Tensor]]


def layer_pairs(prefix: str, ours: nn.Module, theirs: nn.Module) -> Pairs:
    return {f"{prefix}.{name}": (getattr(ours, name), getattr(theirs, name)) for name in ("weight", "bias")}


def encoder_pairs(prefix: str, ours: nn.Module, theirs: RefEncoder) -> Pairs:
    convs = [module for module in ours.convnet if isinstance(module, nn.Conv2d)]
    found: Pairs = {}
    for index, (conv, reference_conv) in enumerate(zip(convs, theirs.convs, strict=True)):
        found.update(layer_pairs(f"{prefix}.convs.{index}", conv, reference_conv))
    found.update(layer_pairs(f"{prefix}.fc", ours.projection[0], theirs.fc))
    found.update(layer_pairs(f"{prefix}.ln", ours.projection[1], theirs.ln))
    return found


def pairs(model: CURL, reference: RefAgent) -> Pairs:
    """Each sb3-ef parameter beside the reference's, by the reference's name."""
    found: Pairs = {}
    for name, ours, theirs in (
        ("critic", model.critic, reference.critic),
        ("critic_target", model.critic_target, reference.critic_target),
    ):
        found.update(encoder_pairs(f"{name}.encoder", ours.features_extractor, theirs.encoder))
        for head, q_network in (("Q1", ours.qf0), ("Q2", ours.qf1)):
            for index in (0, 2, 4):
                found.update(layer_pairs(f"{name}.{head}.{index}", q_network[index], getattr(theirs, head)[index]))
    actor = model.actor
    found.update(encoder_pairs("actor.encoder", actor.features_extractor, reference.actor.encoder))
    for index in (0, 2):
        found.update(layer_pairs(f"actor.trunk.{index}", actor.latent_pi[index], reference.actor.trunk[index]))
    last = reference.actor.trunk[4]
    found["actor.trunk.4.weight"] = (th.cat([actor.mu.weight, actor.log_std.weight]), last.weight)
    found["actor.trunk.4.bias"] = (th.cat([actor.mu.bias, actor.log_std.bias]), last.bias)
    found["log_alpha"] = (model.log_ent_coef.reshape(()), reference.log_alpha)
    found["W"] = (model.auxiliary.W, reference.curl.W)
    return found


def fixed_batch(seed: int) -> CURLBatch:
    generator = th.Generator().manual_seed(seed)
    frames = th.randint(0, 256, (2, BATCH, 9, FRAME, FRAME), dtype=th.uint8, generator=generator)
    corners = th.randint(0, FRAME - CROP, (3, 2), generator=generator).tolist()
    obs, next_obs, pos = (
        frames[source][:, :, r : r + CROP, c : c + CROP] for source, (r, c) in zip((0, 1, 0), corners, strict=True)
    )
    actions = th.rand(BATCH, 2, generator=generator) * 2 - 1
    rewards = th.rand(BATCH, 1, generator=generator)
    dones = (th.arange(BATCH) % 3 == 0).float()[:, None]
    return CURLBatch(obs, actions, rewards, next_obs, dones, th.full((BATCH, 1), 0.99), pos)


def assert_parameters_equal(model: CURL, reference: RefAgent, when: str) -> None:
    for name, (ours, theirs) in pairs(model, reference).items():
        th.testing.assert_close(ours, theirs, msg=lambda message, name=name: f"{name} {when}: {message}")


def test_three_updates_match_the_authors_update_to_float_rounding():
    model = make_model()
    reference = reference_of(model)
    assert_parameters_equal(model, reference, "after copying")
    before = {name: ours.detach().clone() for name, (ours, _) in pairs(model, reference).items()}
    for step in range(3):
        batch = fixed_batch(step)
        th.manual_seed(10 + step)
        logs = model._update(batch, step=step)
        th.manual_seed(10 + step)
        expected = reference.update(
            batch.observations.float(), batch.actions, batch.rewards, batch.next_observations.float(),
            1 - batch.dones, batch.positives.float(), step,
        )  # fmt: skip
        diagnostics = {"aux_grad_ratio"} if step == 0 else set()  # the first update and one in a hundred
        assert set(logs) == {"ent_coef", *expected, *diagnostics}
        for name, value in expected.items():
            th.testing.assert_close(
                logs[name], value, msg=lambda message, where=f"{name} at {step}": f"{where}: {message}"
            )
        assert_parameters_equal(model, reference, f"after update {step}")
    after = {name: ours.detach() for name, (ours, _) in pairs(model, reference).items()}
    # Every parameter moved (the critic target by the soft updates of updates 0 and 2).
    assert all(not th.equal(before[name], after[name]) for name in before)


def test_actor_temperature_and_targets_move_on_even_updates_only_and_each_optimiser_in_the_authors_order():
    model = make_model()
    order: list[str] = []
    optimizers = {
        "critic": model.critic.optimizer, "actor": model.actor.optimizer, "temperature": model.ent_coef_optimizer,
        "encoder": model.encoder_optimizer, "curl": model.auxiliary_optimizer,
    }  # fmt: skip
    for name, optimizer in optimizers.items():
        optimizer.register_step_post_hook(lambda *_, name=name: order.append(name))
    watched = {
        "actor": model.actor.latent_pi[0].weight,
        "alpha": model.log_ent_coef,
        "target head": model.critic_target.qf0[0].weight,
        "target encoder": model.critic_target.features_extractor.projection[0].weight,
    }
    for step in range(3):
        snapshot = {name: value.detach().clone() for name, value in watched.items()}
        order.clear()
        model._update(fixed_batch(step), step=step)
        moved = {name for name, value in watched.items() if not th.equal(snapshot[name], value)}
        if step % 2 == 0:
            assert order == ["critic", "actor", "temperature", "encoder", "curl"]
            assert moved == set(watched)
        else:
            assert order == ["critic", "encoder", "curl"]
            assert moved == set()


def test_each_optimiser_holds_the_authors_parameters_with_their_learning_rates_and_betas():
    model = make_model()

    def held(optimizer: th.optim.Optimizer) -> set[int]:
        return {id(parameter) for group in optimizer.param_groups for parameter in group["params"]}

    def ids(*modules: nn.Module) -> set[int]:
        return {id(parameter) for module in modules for parameter in module.parameters()}

    actor, critic = model.actor, model.critic
    encoder = critic.features_extractor
    # The actor's convolutions are the critic's, trained by the critic and CURL only: the actor's Adam holds its MLP
    # and its encoder's linear layer and LayerNorm.
    assert actor.features_extractor.convnet is encoder.convnet
    assert held(actor.optimizer) == ids(actor.latent_pi, actor.mu, actor.log_std, actor.features_extractor.projection)
    assert held(critic.optimizer) == ids(critic)
    assert held(model.ent_coef_optimizer) == {id(model.log_ent_coef)}
    assert held(model.encoder_optimizer) == ids(encoder)
    assert held(model.auxiliary_optimizer) == ids(encoder) | {id(model.auxiliary.W)}
    settings = {
        "actor": (actor.optimizer, LR, (0.9, 0.999)), "critic": (critic.optimizer, LR, (0.9, 0.999)),
        "temperature": (model.ent_coef_optimizer, 1e-4, (0.5, 0.999)),
        "encoder": (model.encoder_optimizer, ENCODER_LR, (0.9, 0.999)),
        "curl": (model.auxiliary_optimizer, ENCODER_LR, (0.9, 0.999)),
    }  # fmt: skip
    for name, (optimizer, lr, betas) in settings.items():
        assert isinstance(optimizer, th.optim.Adam), name
        assert [(group["lr"], group["betas"]) for group in optimizer.param_groups] == [(lr, betas)], name
    # The key encoder is the critic target's encoder, not a copy of its own.
    assert model.auxiliary.key_encoder is model.critic_target.features_extractor
    assert set(model.auxiliary.state_dict()) == {"W", "updates"}


def test_initialisation_is_the_authors():
    model = make_model()
    actor, critic = model.actor, model.critic
    linears = [*actor.latent_pi, *critic.qf0, *critic.qf1, actor.features_extractor.projection[0]]
    for layer in (layer for layer in linears if isinstance(layer, nn.Linear)):
        weight = layer.weight if layer.out_features <= layer.in_features else layer.weight.T
        th.testing.assert_close(weight @ weight.T, th.eye(len(weight)), atol=1e-5, rtol=0)
        assert not layer.bias.any()
    # Mean and log-std are the halves of one orthogonal Linear(hidden, 2 * action_dim), as the authors' last layer.
    joint = th.cat([model.actor.mu.weight, model.actor.log_std.weight])
    th.testing.assert_close(joint @ joint.T, th.eye(4), atol=1e-5, rtol=0)
    assert not model.actor.mu.bias.any() and not model.actor.log_std.bias.any()
    assert model.log_ent_coef.exp().item() == pytest.approx(0.1)  # init_temperature
    assert model.target_entropy == -2.0


def test_log_std_is_the_authors_tanh_mapping_into_minus_10_and_2():
    model = make_model()
    observations = th.randint(0, 256, (3, 9, FRAME, FRAME), dtype=th.uint8)
    with th.no_grad():
        model.actor.log_std.weight.zero_()
        for z in (-3.0, 0.0, 0.5, 4.0):
            model.actor.log_std.bias.fill_(z)
            _, log_std, _ = model.actor.get_action_dist_params(observations)
            th.testing.assert_close(log_std, th.full((3, 2), -10 + 6 * (math.tanh(z) + 1)))
    # At z = 0 the std is exp(-4), about 0.018 (SB3's clamp would give exp(0) = 1).
    assert math.exp(-10 + 6 * (math.tanh(0.0) + 1)) == pytest.approx(0.0183, abs=1e-4)
