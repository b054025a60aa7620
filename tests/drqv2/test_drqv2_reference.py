"""DrQ-v2, DrQv2-EF and SEAR against DrQ-v2's update (facebookresearch/drqv2, ``drqv2.py``): a transcription of its
equations written here, independently of sb3-ef's code, given sb3-ef's initial weights, and run side by side on
fixed batches.

The reference encodes the augmented observations, steps the encoder and critic on the clipped double-Q loss against
``r + discount * min(Q1', Q2')(h', clipped noisy actor mean)`` (next features without gradient, the std from its
linear schedule), steps the actor on ``-min(Q1, Q2)(h, noisy actor mean)`` of detached features, then moves the
critic target by Polyak averaging. DrQv2-EF adds ``beta * L_ef`` (the EF authors' loss: agent features rolled
forward k actions, decoded with the scene features, squared error to frame t+k / 255 summed over pixels, averaged
over the valid samples) and SEAR ``1 * reconstruction + 0.25 * mask`` (sear-rl: the halves of the latent decoded
to the frames in [-0.5, 0.5] and to the agent masks, squared error and BCE summed over pixels, averaged over the
batch) to the critic's loss, their modules stepped with the encoder. The EF rollout network and decoder and the
SEAR decoders are copies of sb3-ef's modules (their layers are tested in tests/ef and tests/sear); everything
else is written here.

The augmented batch is taken from sb3-ef's update (each sample checked to be one shift of at most 4 pixels of the
stored frames, the same for the observation and its EF target or agent masks), and the reference continues from
the global random state the augmentation left, so that both draw the same exploration noise. Every loss and every
parameter after each of three updates agree to float rounding.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

import pytest
import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ef import SEAR, DrQv2, DrQv2EF
from sb3_ef.envs.toy import ToyAgentEnv

FRAME, BATCH, HIDDEN, TRUNK, FEATURES, AGENT, HORIZON = 32, 6, 16, 8, 64, 8, 3
# A tau, clip and std schedule far from the defaults, so that a swapped constant shows.
TAU, LR, CLIP, STD_SCHEDULE = 0.3, 2e-3, 0.2, (0.9, 0.2, 40)  # the std: "linear(0.9,0.2,40)"
BETA = 0.7  # EF's weight, away from 1 so that a missing beta shows
TIMESTEPS = (0, 17, 60)  # the std of each update: on the schedule's slope, then past its end
PAD = 4
# Adam divides by the root of the squared gradient: a gradient at rounding level moves a weight by up to LR, in a
# direction rounding decides. A twentieth of an Adam step is far below what a change in the maths moves.
ADAM_ROUNDING = LR / 20


# The reference, transcribed from drqv2.py (Encoder, Actor, Critic, DrQV2Agent) and utils.py (TruncatedNormal,
# schedule, soft_update_params), with the EF authors' pooled projection of the encoder.


class RefEncoder(nn.Module):
    def __init__(self, channels: int, size: int, features_dim: int | None):
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(channels, 32, 3, stride=2), *(nn.Conv2d(32, 32, 3) for _ in range(3))])
        conv = (size - 3) // 2 + 1 - 6
        self.fc = None if features_dim is None else nn.Linear(32 * (conv // 4) ** 2, features_dim)

    def forward(self, obs: th.Tensor) -> th.Tensor:
        h = obs / 255.0 - 0.5
        for conv in self.convs:
            h = th.relu(conv(h))
        if self.fc is None:
            return h.view(h.shape[0], -1)
        return self.fc(F.avg_pool2d(h, 4, 4).flatten(1))


def trunk(repr_dim: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(repr_dim, TRUNK), nn.LayerNorm(TRUNK), nn.Tanh())


def mlp(inputs: int, outputs: int) -> nn.Sequential:
    layers = [nn.Linear(inputs, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, HIDDEN), nn.ReLU(), nn.Linear(HIDDEN, outputs)]
    return nn.Sequential(*layers)


class RefActor(nn.Module):
    def __init__(self, repr_dim: int, action_dim: int):
        super().__init__()
        self.trunk, self.policy = trunk(repr_dim), mlp(TRUNK, action_dim)

    def forward(self, obs: th.Tensor, std: float) -> tuple[th.Tensor, float]:
        return th.tanh(self.policy(self.trunk(obs))), std


def truncated_normal_sample(mu: th.Tensor, std: float, clip: float, eps: float = 1e-6) -> th.Tensor:
    noise = th.empty(mu.shape, dtype=mu.dtype).normal_() * std
    x = mu + th.clamp(noise, -clip, clip)
    clamped = th.clamp(x, -1.0 + eps, 1.0 - eps)
    return x - x.detach() + clamped.detach()


class RefCritic(nn.Module):
    def __init__(self, repr_dim: int, action_dim: int):
        super().__init__()
        self.trunk = trunk(repr_dim)
        self.Q1, self.Q2 = mlp(TRUNK + action_dim, 1), mlp(TRUNK + action_dim, 1)

    def forward(self, obs: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        h_action = th.cat([self.trunk(obs), action], dim=-1)
        return self.Q1(h_action), self.Q2(h_action)


def schedule(step: int) -> float:
    init, final, duration = STD_SCHEDULE
    mix = min(max(step / duration, 0.0), 1.0)
    return (1.0 - mix) * init + mix * final


def soft_update_params(net: nn.Module, target_net: nn.Module, tau: float) -> None:
    for param, target_param in zip(net.parameters(), target_net.parameters(), strict=True):
        target_param.data.copy_(tau * param.data + (1 - tau) * target_param.data)


def ef_loss(rollout: nn.Module, decoder: nn.Module, h: th.Tensor, targets: Any) -> tuple[th.Tensor, dict]:
    """The EF authors' loss: h_a rolled forward k actions, decoded with h_s, squared error summed over pixels."""
    h_agent, h_scene = h[:, :AGENT], h[:, AGENT:]
    states = []
    for t in range(int(targets.steps.max())):
        h_agent = rollout(th.cat([h_agent, targets.actions[:, t]], dim=-1))
        states.append(h_agent)
    agent_k = th.stack(states, dim=1)[th.arange(h.shape[0]), targets.steps - 1]
    error = (decoder(th.cat([agent_k, h_scene], dim=-1)) - targets.target.float() / 255.0).pow(2).flatten(1).sum(1)
    valid = targets.valid.float()
    loss = (error * valid).sum() / valid.sum().clamp(min=1.0)
    return BETA * loss, {"ef_loss": loss}


def sear_loss(frame_decoder: nn.Module, mask_decoder: nn.Module, h: th.Tensor, targets: Any) -> tuple[th.Tensor, dict]:
    """sear-rl's loss: reconstruction of the frames and prediction of the agent masks from the latent's halves."""
    first, second = h.chunk(2, dim=1)
    frames = th.clamp(frame_decoder(first), -0.5, 0.5)
    reconstruction = (frames - (targets.frames.float() / 255.0 - 0.5)).pow(2).flatten(1).sum(1).mean()
    masks = th.sigmoid(mask_decoder(second))
    mask = F.binary_cross_entropy(masks, targets.masks.float(), reduction="none").flatten(1).sum(1).mean()
    return 1.0 * reconstruction + 0.25 * mask, {"reconstruction_loss": reconstruction, "mask_loss": mask}


class RefAgent:
    """DrQV2Agent.update on augmented observations, with an auxiliary loss added to the critic's."""

    def __init__(self, encoder: RefEncoder, actor: RefActor, critic: RefCritic, target: RefCritic, auxiliary):
        self.encoder, self.actor, self.critic, self.critic_target = encoder, actor, critic, target
        self.auxiliary_modules, self.auxiliary_loss = auxiliary
        self.auxiliary_modules.train(True)  # DrQV2Agent.train(True) before its updates (EF's decoder has BatchNorm)
        self.encoder_opt = th.optim.Adam(encoder.parameters(), lr=LR)
        self.actor_opt = th.optim.Adam(actor.parameters(), lr=LR)
        self.critic_opt = th.optim.Adam(critic.parameters(), lr=LR)
        self.auxiliary_opt = th.optim.Adam(self.auxiliary_modules.parameters(), lr=LR) if auxiliary[1] else None

    def update_critic(self, obs, action, reward, discount, next_obs, step, targets) -> dict[str, th.Tensor]:
        with th.no_grad():
            stddev = schedule(step)
            mu, std = self.actor(next_obs, stddev)
            next_action = truncated_normal_sample(mu, std, CLIP)
            target_Q1, target_Q2 = self.critic_target(next_obs, next_action)
            target_V = th.min(target_Q1, target_Q2)
            target_Q = reward + (discount * target_V)
        Q1, Q2 = self.critic(obs, action)
        critic_loss = F.mse_loss(Q1, target_Q) + F.mse_loss(Q2, target_Q)
        loss, parts = critic_loss, {}
        if self.auxiliary_loss is not None:
            auxiliary_loss, parts = self.auxiliary_loss(obs, targets)
            loss = critic_loss + auxiliary_loss
            self.auxiliary_opt.zero_grad(set_to_none=True)
        self.encoder_opt.zero_grad(set_to_none=True)
        self.critic_opt.zero_grad(set_to_none=True)
        loss.backward()
        self.critic_opt.step()
        self.encoder_opt.step()
        if self.auxiliary_opt is not None:
            self.auxiliary_opt.step()
        return {"critic_loss": critic_loss, "q_values": th.cat([Q1, Q2], dim=1).mean(), **parts}

    def update_actor(self, obs, step) -> th.Tensor:
        mu, std = self.actor(obs, schedule(step))
        action = truncated_normal_sample(mu, std, CLIP)
        Q1, Q2 = self.critic(obs, action)
        actor_loss = -th.min(Q1, Q2).mean()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_opt.step()
        return actor_loss

    def update(self, obs, action, reward, discount, next_obs, step, targets=None) -> dict[str, th.Tensor]:
        obs = self.encoder(obs.float())
        with th.no_grad():
            next_obs = self.encoder(next_obs.float())
        metrics = self.update_critic(obs, action, reward, discount, next_obs, step, targets)
        metrics["actor_loss"] = self.update_actor(obs.detach(), step)
        soft_update_params(self.critic, self.critic_target, TAU)
        return {name: value.detach() for name, value in metrics.items()}


# sb3-ef's models, and the reference given their weights.


def make_model(algorithm: type) -> DrQv2:
    arguments: dict[str, Any] = {
        "learning_rate": LR, "tau": TAU, "target_noise_clip": CLIP, "exploration_std": "linear(0.9,0.2,40)",
        "buffer_size": 200, "batch_size": BATCH, "learning_starts": 41, "seed": 0, "device": "cpu",
        "policy_kwargs": {"net_arch": [HIDDEN, HIDDEN], "trunk_dim": TRUNK},
    }  # fmt: skip
    if algorithm is DrQv2EF:
        arguments.update(ef_horizon=HORIZON, babbling_steps=0, beta=BETA)
        ef_kwargs = {"rollout_hidden_dims": (16,), "decoder_channels": 8}
        arguments["policy_kwargs"].update(features_dim=FEATURES, agent_dim=AGENT, ef_kwargs=ef_kwargs)
    elif algorithm is SEAR:
        arguments["policy_kwargs"].update(features_dim=FEATURES)
    env = ToyAgentEnv(size=FRAME, max_episode_steps=10, agent_masks=algorithm is SEAR)
    model = algorithm("CnnPolicy", env, **arguments)
    model.learn(40)  # fills the buffer (before learning_starts: no update)
    return model


def copy_sequential(reference: nn.Sequential, ours: nn.Sequential) -> None:
    """Copy the weights of ``ours``'s layers into ``reference``'s layers with weights, in order."""
    mine = [layer for layer in reference if isinstance(layer, (nn.Linear, nn.LayerNorm))]
    theirs = [layer for layer in ours if isinstance(layer, (nn.Linear, nn.LayerNorm))]
    for reference_layer, layer in zip(mine, theirs, strict=True):
        reference_layer.load_state_dict(layer.state_dict())


def reference_of(model: DrQv2) -> RefAgent:
    policy = model.policy
    encoder = RefEncoder(9, FRAME, policy.features_dim)
    convs = [layer for layer in policy.encoder.convnet if isinstance(layer, nn.Conv2d)]
    for reference_conv, conv in zip(encoder.convs, convs, strict=True):
        reference_conv.load_state_dict(conv.state_dict())
    if encoder.fc is not None:
        encoder.fc.load_state_dict(policy.encoder.projection[2].state_dict())
    repr_dim = policy.encoder.features_dim
    actor = RefActor(repr_dim, 2)
    copy_sequential(actor.trunk, policy.actor.trunk)
    copy_sequential(actor.policy, policy.actor.mu)
    critic, target = RefCritic(repr_dim, 2), RefCritic(repr_dim, 2)
    for reference_critic, ours in ((critic, policy.critic), (target, policy.critic_target)):
        copy_sequential(reference_critic.trunk, ours.trunk)
        copy_sequential(reference_critic.Q1, ours.q_networks[0])
        copy_sequential(reference_critic.Q2, ours.q_networks[1])
    auxiliary: tuple[nn.Module, Callable | None] = (nn.ModuleList(), None)
    if isinstance(model, DrQv2EF):
        rollout, decoder = copy.deepcopy(model.ef.rollout_block.net), copy.deepcopy(model.ef.decoder)
        auxiliary = (nn.ModuleList([rollout, decoder]), lambda h, targets: ef_loss(rollout, decoder, h, targets))
    elif isinstance(model, SEAR):
        frames, masks = copy.deepcopy(model.auxiliary.frame_decoder), copy.deepcopy(model.auxiliary.mask_decoder)
        auxiliary = (nn.ModuleList([frames, masks]), lambda h, targets: sear_loss(frames, masks, h, targets))
    return RefAgent(encoder, actor, critic, target, auxiliary)


def pairs(model: DrQv2, reference: RefAgent) -> dict[str, tuple[th.Tensor, th.Tensor]]:
    """Each sb3-ef parameter beside the reference's, in the order of the modules' parameters."""
    policy = model.policy
    modules = {
        "encoder": (policy.encoder, reference.encoder),
        "actor": (policy.actor, reference.actor),
        "critic": (policy.critic, reference.critic),
        "critic_target": (policy.critic_target, reference.critic_target),
    }
    if isinstance(model, DrQv2EF):
        modules["ef"] = (nn.ModuleList([model.ef.rollout_block.net, model.ef.decoder]), reference.auxiliary_modules)
    elif isinstance(model, SEAR):
        sear = model.auxiliary
        modules["sear"] = (nn.ModuleList([sear.frame_decoder, sear.mask_decoder]), reference.auxiliary_modules)
    found = {}
    for name, (ours, theirs) in modules.items():
        ours_parameters, their_parameters = list(ours.parameters()), list(theirs.parameters())
        assert len(ours_parameters) == len(their_parameters), name
        for index, (mine, reference_parameter) in enumerate(zip(ours_parameters, their_parameters, strict=True)):
            found[f"{name}.{index}"] = (mine, reference_parameter)
    return found


def is_one_shift(*originals_and_results: tuple[th.Tensor, th.Tensor]) -> bool:
    """Whether one offset of at most PAD pixels (replicate padding) maps each original to its result."""
    height, width = originals_and_results[0][0].shape[-2:]
    for dy in range(-PAD, PAD + 1):
        for dx in range(-PAD, PAD + 1):
            rows, cols = (th.arange(height) + dy).clamp(0, height - 1), (th.arange(width) + dx).clamp(0, width - 1)
            if all(th.equal(result, original[:, rows][:, :, cols]) for original, result in originals_and_results):
                return True
    return False


def augmented_update(model: DrQv2, batch: Any) -> tuple[dict[str, th.Tensor], tuple[Any, ...], th.Tensor]:
    """sb3-ef's update of ``batch``, with the augmented batch it drew and the random state the augmentation left."""
    seen: dict[str, Any] = {}
    augment = model._augment

    def recorded(batch: Any) -> Any:
        seen["augmented"] = augment(batch)
        seen["state"] = th.get_rng_state()
        return seen["augmented"]

    model._augment = recorded  # type: ignore[method-assign]
    try:
        logs = model._update(batch)
    finally:
        del model._augment
    return logs, seen["augmented"], seen["state"]


def check_shifts(batch: Any, observations: th.Tensor, next_observations: th.Tensor, targets: Any) -> None:
    for sample in range(BATCH):
        assert is_one_shift((batch.next_observations[sample], next_observations[sample]))
        together = [(batch.observations[sample], observations[sample])]
        if targets is not None and hasattr(targets, "steps"):  # EF: frame t+k moves with the observation
            frame = batch.future_frames[sample, int(targets.steps[sample]) - 1]
            together.append((frame, targets.target[sample]))
        elif targets is not None:  # SEAR: the agent masks move with their frames
            together.append((batch.masks[sample], targets.masks[sample]))
        assert is_one_shift(*together)


@pytest.mark.parametrize("algorithm", [DrQv2, DrQv2EF, SEAR])
def test_three_updates_match_drqv2s_update_to_float_rounding(algorithm):
    model = make_model(algorithm)
    reference = reference_of(model)
    before = {name: ours.detach().clone() for name, (ours, _) in pairs(model, reference).items()}
    for name, (ours, theirs) in pairs(model, reference).items():
        assert th.equal(ours, theirs), name
    model.policy.set_training_mode(True)
    for update, timesteps in enumerate(TIMESTEPS):
        model.num_timesteps = timesteps
        batch = model.replay_buffer.sample(BATCH)
        th.manual_seed(100 + update)
        logs, (observations, next_observations, targets), state = augmented_update(model, batch)
        check_shifts(batch, observations, next_observations, targets)
        th.set_rng_state(state)
        expected = reference.update(
            observations, batch.actions, batch.rewards, (1.0 - batch.dones) * batch.discounts, next_observations,
            timesteps, targets,
        )  # fmt: skip
        assert set(expected) <= set(logs)
        for name, value in expected.items():
            th.testing.assert_close(logs[name], value, msg=lambda m, where=f"{name} at {update}": f"{where}: {m}")
        for name, (ours, theirs) in pairs(model, reference).items():
            th.testing.assert_close(
                ours,
                theirs,
                atol=ADAM_ROUNDING,
                rtol=1e-4,
                msg=lambda m, where=f"{name} after {update}": f"{where}: {m}",
            )
    after = {name: ours.detach() for name, (ours, _) in pairs(model, reference).items()}
    moved = [name for name in before if not th.equal(before[name], after[name])]
    assert len(moved) == len(before), sorted(set(before) - set(moved))
