"""DrQv2-EF's update in one file: a reading copy, CleanRL style, of one gradient step of ``sb3_ef.DrQv2EF``.

The package spreads this step over the host, the auxiliary-loss interface, the Ego-Foresight module and the replay
buffer, so that every host shares them. This file writes it top to bottom instead, importing nothing from sb3-ef
(its demo at the bottom takes sb3-ef's toy world):

1. the n-step transition and the EF window of a step, read from whole episodes (what the replay buffer samples);
2. DrQ-v2's random shift, networks and update (facebookresearch/drqv2, ``drqv2.py`` and ``utils.py``);
3. Ego-Foresight (the EF authors' code): the encoder's pooled projection, the split of the features into agent
   and scene parts, the rollout MLP, the DCGAN decoder, and the loss added to the critic's.

tests/drqv2/test_drqv2_reference.py runs this update beside ``DrQv2EF``'s (and ``DrQv2``'s, and ``SEAR``'s with
SEAR's loss in EF's place) from the same weights, episodes and random draws, and holds every loss and every
parameter equal to float rounding: what you read here is what the package computes.

``python examples/drqv2_ef_single_file.py`` runs a few updates on sb3-ef's tiny pixel world (CPU, seconds).
"""

from __future__ import annotations

import copy
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
import torch as th
from torch import nn
from torch.nn import functional as F


@dataclass
class Config:
    """The hyper-parameters of one update (DrQv2EF's defaults, docs/drqv2.md)."""

    learning_rate: float = 1e-4  # Adam, every network
    gamma: float = 0.99
    n_steps: int = 3  # n of the n-step return
    tau: float = 0.01  # Polyak step of the critic target
    std_schedule: tuple[float, float, int] = (1.0, 0.1, 500_000)  # exploration std "linear(1.0,0.1,500000)"
    target_noise_clip: float = 0.3
    pad: int = 4  # random shift of at most 4 pixels
    features_dim: int | None = 2048  # the EF authors' pooled projection; None: DrQ-v2's flattened conv features
    trunk_dim: int = 50
    hidden_dims: tuple[int, ...] = (1024, 1024)  # actor and each Q head
    beta: float = 1.0  # weight of EF's loss
    horizon: int = 10  # H: k is drawn in [1, H]
    agent_dim: int = 32  # h_a: the first agent_dim features of h; h_s: the rest
    rollout_hidden_dims: tuple[int, ...] = (512, 512)
    decoder_channels: int = 64


# 1. Episodes, n-step transitions and EF windows.


@dataclass
class Episode:
    """One episode as the env played it: T + 1 stacked uint8 observations (3k, h, w), oldest frame first, T actions
    and T rewards; ``terminated`` when a termination ended it (no bootstrap), False for a time limit or an episode
    still running (both bootstrap)."""

    observations: list[np.ndarray]
    actions: list[np.ndarray]
    rewards: list[float]
    terminated: bool


def n_step_transition(episode: Episode, t: int, n_steps: int, gamma: float) -> tuple[float, float, float, np.ndarray]:
    """From step t, over the m = min(n, steps left) next steps: sum_{i<m} gamma^i r_{t+i}, gamma^m, done (1 when the
    episode terminated at step t + m - 1) and the observation at t + m."""
    m = min(n_steps, len(episode.rewards) - t)
    reward = sum(gamma**i * episode.rewards[t + i] for i in range(m))
    done = episode.terminated and t + m == len(episode.rewards)
    return reward, gamma**m, float(done), episode.observations[t + m]


def foresight_window(episode: Episode, t: int, k: int, horizon: int) -> tuple[np.ndarray, np.ndarray, bool]:
    """EF's window from step t: frame t + k (the newest of observation t + k), actions t .. t + H - 1 (zeros after the
    episode's last step) and whether step t + k - 1 was taken inside the episode (else the frame is zeros)."""
    steps = len(episode.actions)
    valid = t + k <= steps
    frame = episode.observations[t + k][-3:] if valid else np.zeros_like(episode.observations[0][-3:])  # RGB: 3
    actions = [episode.actions[i] if i < steps else np.zeros_like(episode.actions[0]) for i in range(t, t + horizon)]
    return frame, np.stack(actions), valid


@dataclass
class Batch:
    """A batch of n-step transitions and EF windows (uint8 frames, float32 values)."""

    observations: th.Tensor  # (B, 3k, h, w) at t
    actions: th.Tensor  # (B, A) at t
    rewards: th.Tensor  # (B, 1) n-step discounted sums
    discounts: th.Tensor  # (B, 1) gamma^m
    dones: th.Tensor  # (B, 1) 1 for a termination within the m steps
    next_observations: th.Tensor  # (B, 3k, h, w) at t + m
    ef_step: int  # k, one per batch (the EF authors' code)
    ef_frames: th.Tensor  # (B, 3, h, w) frame t + k
    ef_actions: th.Tensor  # (B, H, A) actions t .. t + H - 1
    ef_valid: th.Tensor  # (B,) bool: frame t + k lies inside the episode


def make_batch(episodes: list[Episode], samples: list[tuple[int, int]], k: int, cfg: Config) -> Batch:
    """The batch of the (episode, step) ``samples`` with rollout length ``k``."""
    transitions = [n_step_transition(episodes[e], t, cfg.n_steps, cfg.gamma) for e, t in samples]
    windows = [foresight_window(episodes[e], t, k, cfg.horizon) for e, t in samples]

    def column(values: list, dtype: th.dtype | None = None) -> th.Tensor:
        return th.as_tensor(np.stack([np.asarray(value) for value in values]), dtype=dtype)

    def values(index: int) -> th.Tensor:
        return column([transition[index] for transition in transitions], th.float32)[:, None]

    return Batch(
        observations=column([episodes[e].observations[t] for e, t in samples]),
        actions=column([episodes[e].actions[t] for e, t in samples], th.float32),
        rewards=values(0),
        discounts=values(1),
        dones=values(2),
        next_observations=column([transition[3] for transition in transitions]),
        ef_step=k,
        ef_frames=column([window[0] for window in windows]),
        ef_actions=column([window[1] for window in windows], th.float32),
        ef_valid=column([window[2] for window in windows], th.bool),
    )


# 2. DrQ-v2: random shift, networks, update.


def weight_init(module: nn.Module) -> None:
    """DrQ-v2's initialisation: orthogonal weights (ReLU gain on convolutions), zero biases."""
    if isinstance(module, (nn.Linear, nn.Conv2d)):
        gain = nn.init.calculate_gain("relu") if isinstance(module, nn.Conv2d) else 1.0
        nn.init.orthogonal_(module.weight, gain)
        if module.bias is not None:
            nn.init.zeros_(module.bias)


def draw_shifts(batch_size: int, pad: int) -> th.Tensor:
    """One (dy, dx) offset in [-pad, pad] per sample: (B, 2)."""
    return th.randint(-pad, pad + 1, (batch_size, 2))


def shift(images: th.Tensor, offsets: th.Tensor) -> th.Tensor:
    """Each sample moved by its offset, edge pixels repeated: DrQ-v2's replicate pad and random crop (integer
    offsets), as ``out[:, i, j] = image[:, clamp(i + dy), clamp(j + dx)]``."""
    height, width = images.shape[-2:]
    rows = (th.arange(height)[None, :] + offsets[:, :1]).clamp(0, height - 1)  # (B, h)
    cols = (th.arange(width)[None, :] + offsets[:, 1:]).clamp(0, width - 1)  # (B, w)
    batch = th.arange(images.shape[0])[:, None, None]
    return images.permute(0, 2, 3, 1)[batch, rows[:, :, None], cols[:, None, :]].permute(0, 3, 1, 2)


def augment(batch: Batch, offsets: th.Tensor, next_offsets: th.Tensor) -> Batch:
    """The observations shifted, frame t + k moved with its observation; the next observations shifted apart."""
    return dataclasses.replace(
        batch,
        observations=shift(batch.observations, offsets),
        ef_frames=shift(batch.ef_frames, offsets),
        next_observations=shift(batch.next_observations, next_offsets),
    )


class Encoder(nn.Module):
    """DrQ-v2's conv stack on obs / 255 - 0.5; with ``features_dim``, EF's 4x4 average pool and linear projection."""

    def __init__(self, channels: int, size: int, features_dim: int | None):
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(channels, 32, 3, stride=2), *(nn.Conv2d(32, 32, 3) for _ in range(3))])
        conv = (size - 3) // 2 + 1 - 6  # the conv map's side
        self.repr_dim = 32 * conv**2 if features_dim is None else features_dim
        self.fc = None if features_dim is None else nn.Linear(32 * (conv // 4) ** 2, features_dim)
        self.apply(weight_init)

    def forward(self, obs: th.Tensor) -> th.Tensor:
        h = obs.float() / 255.0 - 0.5
        for conv in self.convs:
            h = th.relu(conv(h))
        if self.fc is None:
            return h.flatten(1)
        return self.fc(F.avg_pool2d(h, 4, 4).flatten(1))


def trunk(repr_dim: int, cfg: Config) -> nn.Sequential:
    return nn.Sequential(nn.Linear(repr_dim, cfg.trunk_dim), nn.LayerNorm(cfg.trunk_dim), nn.Tanh())


def mlp(inputs: int, hidden_dims: tuple[int, ...], outputs: int) -> nn.Sequential:
    dims = [inputs, *hidden_dims]
    layers = [layer for i in range(len(hidden_dims)) for layer in (nn.Linear(dims[i], dims[i + 1]), nn.ReLU())]
    return nn.Sequential(*layers, nn.Linear(dims[-1], outputs))


class Actor(nn.Module):
    """The mean action tanh(mlp(trunk(h)))."""

    def __init__(self, repr_dim: int, action_dim: int, cfg: Config):
        super().__init__()
        self.trunk, self.policy = trunk(repr_dim, cfg), mlp(cfg.trunk_dim, cfg.hidden_dims, action_dim)
        self.apply(weight_init)

    def forward(self, h: th.Tensor) -> th.Tensor:
        return th.tanh(self.policy(self.trunk(h)))


class Critic(nn.Module):
    """Two Q heads on [trunk(h), a]."""

    def __init__(self, repr_dim: int, action_dim: int, cfg: Config):
        super().__init__()
        self.trunk = trunk(repr_dim, cfg)
        self.Q1 = mlp(cfg.trunk_dim + action_dim, cfg.hidden_dims, 1)
        self.Q2 = mlp(cfg.trunk_dim + action_dim, cfg.hidden_dims, 1)
        self.apply(weight_init)

    def forward(self, h: th.Tensor, action: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        h_action = th.cat([self.trunk(h), action], dim=-1)
        return self.Q1(h_action), self.Q2(h_action)


def std_at(step: int, cfg: Config) -> float:
    """The exploration std: linear from its initial to its final value over ``duration`` agent steps."""
    initial, final, duration = cfg.std_schedule
    mix = min(max(step / duration, 0.0), 1.0)
    return (1.0 - mix) * initial + mix * final


def noisy_action(mean: th.Tensor, std: float, clip: float, eps: float = 1e-6) -> th.Tensor:
    """DrQ-v2's truncated normal sample: mean + clip(N(0, std^2)), clamped inside the bounds with the gradient of
    the unclamped action (straight through)."""
    noise = th.empty(mean.shape, dtype=mean.dtype).normal_() * std
    action = mean + th.clamp(noise, -clip, clip)
    clamped = th.clamp(action, -1.0 + eps, 1.0 - eps)
    return action - action.detach() + clamped.detach()


# 3. Ego-Foresight.


class NormedLinear(nn.Sequential):
    """Linear -> LayerNorm -> Mish (TD-MPC2's block, the rollout MLP's hidden layers)."""

    def __init__(self, inputs: int, outputs: int):
        super().__init__(nn.Linear(inputs, outputs), nn.LayerNorm(outputs), nn.Mish())


def decoder(in_dim: int, frame_shape: tuple[int, int, int], channels: int) -> nn.Sequential:
    """DCGAN-style: the features as a 1x1 map, transposed convolutions (BatchNorm, LeakyReLU 0.2) up to one frame in
    [0, 1] (sigmoid); 1 -> 4 -> 8 -> ... -> size for sizes 4 * 2^n, the authors' 1 -> 5 -> 10 -> 21 -> 42 -> 84."""
    size = frame_shape[1]
    layers = [(5, 1, 0), (4, 2, 1), (5, 2, 1), (4, 2, 1), (4, 2, 1)]  # (kernel, stride, padding) at 84x84
    if size != 84:
        layers = [(4, 1, 0)] + [(4, 2, 1)] * int(math.log2(size // 4))
    modules: list[nn.Module] = []
    for index, (kernel, stride, padding) in enumerate(layers):
        last = index == len(layers) - 1
        in_channels, out_channels = in_dim if index == 0 else channels, frame_shape[0] if last else channels
        modules.append(nn.ConvTranspose2d(in_channels, out_channels, kernel, stride, padding, bias=False))
        modules += [nn.Sigmoid()] if last else [nn.BatchNorm2d(out_channels), nn.LeakyReLU(0.2)]
    for module in modules:  # DCGAN's initialisation
        if isinstance(module, nn.ConvTranspose2d):
            nn.init.normal_(module.weight, 0.0, 0.02)
        elif isinstance(module, nn.BatchNorm2d):
            nn.init.normal_(module.weight, 1.0, 0.02)
            nn.init.zeros_(module.bias)
    return nn.Sequential(*modules)


class EgoForesight(nn.Module):
    """EF's loss: h = [h_a, h_s]; h_a rolled forward by a_t .. a_{t+k-1}, decoded with h_s to frame t + k."""

    def __init__(self, feature_dim: int, action_dim: int, frame_shape: tuple[int, int, int], cfg: Config):
        super().__init__()
        self.agent_dim, self.beta = cfg.agent_dim, cfg.beta
        dims = [cfg.agent_dim + action_dim, *cfg.rollout_hidden_dims]
        blocks = [NormedLinear(dims[i], dims[i + 1]) for i in range(len(cfg.rollout_hidden_dims))]
        self.rollout = nn.Sequential(*blocks, nn.Linear(dims[-1], cfg.agent_dim))  # h_a(t+1) = f([h_a(t), a(t)])
        self.decoder = decoder(feature_dim, frame_shape, cfg.decoder_channels)

    def forward(self, h: th.Tensor, batch: Batch) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """beta * L_ef; L_ef: squared error to frame t + k / 255, summed over pixels, averaged over valid samples."""
        h_agent, h_scene = h[:, : self.agent_dim], h[:, self.agent_dim :]
        for t in range(batch.ef_step):
            h_agent = self.rollout(th.cat([h_agent, batch.ef_actions[:, t]], dim=-1))
        prediction = self.decoder(th.cat([h_agent, h_scene], dim=-1)[:, :, None, None])
        error = (prediction - batch.ef_frames.float() / 255.0).pow(2).flatten(1).sum(dim=1)
        valid = batch.ef_valid.float()  # samples whose frame t + k lies after the episode's end weigh 0
        loss = (error * valid).sum() / valid.sum().clamp(min=1.0)
        return self.beta * loss, {"ef_loss": loss.detach()}


# The update.


class DrQv2EFAgent:
    """DrQV2Agent.update with an auxiliary loss (EF) added to the critic's and stepped with the encoder.

    ``auxiliary(h, batch)`` returns the weighted loss and its logged parts; ``None`` gives DrQ-v2 itself.
    """

    def __init__(self, encoder: Encoder, actor: Actor, critic: Critic, auxiliary: nn.Module | None, cfg: Config):
        self.encoder, self.actor, self.critic, self.auxiliary, self.cfg = encoder, actor, critic, auxiliary, cfg
        self.critic_target = copy.deepcopy(critic)
        self.encoder_opt = th.optim.Adam(encoder.parameters(), lr=cfg.learning_rate)
        self.actor_opt = th.optim.Adam(actor.parameters(), lr=cfg.learning_rate)
        self.critic_opt = th.optim.Adam(critic.parameters(), lr=cfg.learning_rate)
        self.auxiliary_opt = None
        if auxiliary is not None:
            auxiliary.train(True)  # EF's decoder normalises by the batch's statistics
            self.auxiliary_opt = th.optim.Adam(auxiliary.parameters(), lr=cfg.learning_rate)

    def update(self, batch: Batch, step: int) -> dict[str, th.Tensor]:
        """One gradient step on an augmented batch, ``step`` the agent step of the std schedule."""
        h = self.encoder(batch.observations)
        with th.no_grad():
            next_h = self.encoder(batch.next_observations)  # no target encoder
        logs = self.update_critic(h, batch, next_h, std_at(step, self.cfg))
        logs["actor_loss"] = self.update_actor(h.detach(), std_at(step, self.cfg))
        with th.no_grad():  # critic' <- tau * critic + (1 - tau) * critic'
            for param, target in zip(self.critic.parameters(), self.critic_target.parameters(), strict=True):
                target.copy_(self.cfg.tau * param + (1 - self.cfg.tau) * target)
        return logs

    def update_critic(self, h: th.Tensor, batch: Batch, next_h: th.Tensor, std: float) -> dict[str, th.Tensor]:
        """Clipped double Q against r + (1 - done) gamma^m min Q'(h', a'); the encoder and EF learn from it too."""
        with th.no_grad():
            next_action = noisy_action(self.actor(next_h), std, self.cfg.target_noise_clip)
            target_v = th.min(*self.critic_target(next_h, next_action))
            target_q = batch.rewards + (1.0 - batch.dones) * batch.discounts * target_v
        q1, q2 = self.critic(h, batch.actions)
        critic_loss = F.mse_loss(q1, target_q) + F.mse_loss(q2, target_q)
        loss, logs = critic_loss, {"critic_loss": critic_loss.detach(), "q_values": th.cat([q1, q2], 1).mean().detach()}
        optimizers = [self.encoder_opt, self.critic_opt]
        if self.auxiliary is not None and self.auxiliary_opt is not None:
            auxiliary_loss, auxiliary_logs = self.auxiliary(h, batch)
            loss, logs = loss + auxiliary_loss, {**logs, **auxiliary_logs}
            optimizers.append(self.auxiliary_opt)
        for optimizer in optimizers:
            optimizer.zero_grad(set_to_none=True)
        loss.backward()
        for optimizer in optimizers:
            optimizer.step()
        return logs

    def update_actor(self, h: th.Tensor, std: float) -> th.Tensor:
        """-min(Q1, Q2) of the noisy actor action on detached features; only the actor steps."""
        action = noisy_action(self.actor(h), std, self.cfg.target_noise_clip)
        actor_loss = -th.min(*self.critic(h, action)).mean()
        self.actor_opt.zero_grad(set_to_none=True)
        actor_loss.backward()
        self.actor_opt.step()
        return actor_loss.detach()


def main(env_steps: int = 400, updates: int = 30, batch_size: int = 32, seed: int = 0) -> None:
    """Random-action episodes of sb3-ef's toy world, then a few DrQv2-EF updates on uniformly drawn steps."""
    from sb3_ef.envs.toy import ToyAgentEnv

    th.manual_seed(seed)
    rng = np.random.default_rng(seed)
    env = ToyAgentEnv(size=32, max_episode_steps=50)
    episodes: list[Episode] = []
    while sum(len(episode.actions) for episode in episodes) < env_steps:
        episode = Episode([env.reset(seed=seed + len(episodes))[0]], [], [], terminated=False)
        episodes.append(episode)
        ended = False
        while not ended:
            action = rng.uniform(-1.0, 1.0, 2).astype(np.float32)
            observation, reward, episode.terminated, truncated, _ = env.step(action)
            episode.observations.append(observation)
            episode.actions.append(action)
            episode.rewards.append(reward)
            ended = episode.terminated or truncated
    cfg = Config(
        learning_rate=1e-3, features_dim=128, trunk_dim=32, hidden_dims=(64, 64), horizon=5, agent_dim=16,
        rollout_hidden_dims=(64,), decoder_channels=16, std_schedule=(1.0, 0.1, updates),
    )  # fmt: skip
    encoder = Encoder(3 * env.frame_stack, env.size, cfg.features_dim)
    assert cfg.features_dim is not None
    ef = EgoForesight(cfg.features_dim, 2, (3, env.size, env.size), cfg)
    agent = DrQv2EFAgent(encoder, Actor(encoder.repr_dim, 2, cfg), Critic(encoder.repr_dim, 2, cfg), ef, cfg)
    steps = [(e, t) for e, episode in enumerate(episodes) for t in range(len(episode.actions))]
    for update in range(updates):
        samples = [steps[i] for i in rng.integers(len(steps), size=batch_size)]
        batch = make_batch(episodes, samples, int(rng.integers(1, cfg.horizon + 1)), cfg)
        batch = augment(batch, draw_shifts(batch_size, cfg.pad), draw_shifts(batch_size, cfg.pad))
        logs = agent.update(batch, update)
        if update % 5 == 0 or update == updates - 1:
            print(f"update {update:3d}  " + "  ".join(f"{name} {float(value):8.3f}" for name, value in logs.items()))


if __name__ == "__main__":
    main()
