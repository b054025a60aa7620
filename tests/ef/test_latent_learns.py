"""Latent Ego-Foresight puts the agent, not the distractor, into h_a in the toy pixel world, and the probe decoder shows
it: trained afterwards on the frozen features, its saliency with respect to the rolled-out h_a falls on the agent.

A red square moves by the actions, a green square on a random walk, a blue wall is placed per episode. An encoder
trained with latent EF alone (no RL loss, babbling data) must let a linear probe read the agent's position from h_a
far better than the distractor's, and better than the untrained encoder's h_a does.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th
from torch import nn

from sb3_ef.analysis.saliency import decoder_saliency
from sb3_ef.ef import LatentEgoForesight
from sb3_ef.ef.latent import MomentumTarget, draw_other_steps, stacked_observations_at
from sb3_ef.ef.probe import probe_step
from tests.helpers.learning import toy_babbling_windows

HORIZON, EPISODE, SIZE, AGENT_DIM, FEATURES, BATCH = 4, 30, 16, 8, 64, 32


def collect(episodes: int, seed: int) -> dict[str, th.Tensor]:
    """Babbling windows: the context, H actions, H future frames, and the agent / distractor masks at t and t+H."""
    windows = toy_babbling_windows(SIZE, episodes, seed, HORIZON, EPISODE)
    return {**windows, "agent": windows["agent"][:, [0, -1]], "distractor": windows["distractor"][:, [0, -1]]}


def encode(encoder: nn.Module, obs: th.Tensor) -> th.Tensor:
    return encoder(obs.float() / 255 - 0.5)


def train_latent(data: dict[str, th.Tensor], updates: int) -> tuple[nn.Module, LatentEgoForesight]:
    """The hosts' latent EF update without the RL loss (``ForesightLoss.prepare`` / ``forward`` / ``after_update``)."""
    encoder = nn.Sequential(
        nn.Conv2d(9, 16, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.ReLU(),
        nn.Flatten(), nn.Linear(32 * (SIZE // 4) ** 2, FEATURES),
    )  # fmt: skip
    ef = LatentEgoForesight(FEATURES, 2, (3, SIZE, SIZE), agent_dim=AGENT_DIM, horizon=HORIZON,
                            rollout_hidden_dims=(64, 64), decoder_channels=32, step_sampling="sample",
                            projection_dim=32, head_hidden_dim=64)  # fmt: skip
    target = MomentumTarget(encoder, ef.head.projection, 0.01, encode)
    optimizer = th.optim.Adam([*encoder.parameters(), *ef.rollout_block.parameters(), *ef.head.parameters()], lr=1e-3)
    generator = th.Generator().manual_seed(0)
    mask = th.ones(BATCH, HORIZON, dtype=th.bool)
    for _ in range(updates):
        index = th.randint(0, len(data["obs"]), (BATCH,), generator=generator)
        obs, actions, frames = data["obs"][index], data["actions"][index], data["frames"][index]
        steps = ef.draw_steps(mask, generator)
        others = draw_other_steps(mask, steps, HORIZON, generator)
        future = th.cat([stacked_observations_at(obs, frames, steps), stacked_observations_at(obs, frames, others)])
        loss = ef.loss(encode(encoder, obs), actions, steps, target(future))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        target.update(encoder, ef.head.projection)
    return encoder, ef


def position_r2(features: tuple[th.Tensor, th.Tensor], masks: tuple[th.Tensor, th.Tensor]) -> float:
    """R^2 on held-out windows of a ridge regression from features to the square's centroid in the context."""

    def centroid(m: th.Tensor) -> th.Tensor:
        m, axis = m[:, 0].float(), th.arange(SIZE).float()
        total = m.sum((1, 2)).clamp(min=1)
        return th.stack([(m.sum(2) * axis).sum(1) / total, (m.sum(1) * axis).sum(1) / total], 1)

    (x_train, x_test), (y_train, y_test) = features, (centroid(masks[0]), centroid(masks[1]))
    mean, std = x_train.mean(0), x_train.std(0) + 1e-6
    a = th.cat([(x_train - mean) / std, th.ones(len(x_train), 1)], 1)
    b = th.cat([(x_test - mean) / std, th.ones(len(x_test), 1)], 1)
    w = th.linalg.solve(a.T @ a + 1e-2 * th.eye(a.shape[1]), a.T @ y_train)
    return float(1 - ((b @ w - y_test) ** 2).sum() / ((y_test - y_test.mean(0)) ** 2).sum())


def agent_r2(encoder: nn.Module, train: dict[str, th.Tensor], test: dict[str, th.Tensor], what: str) -> float:
    with th.no_grad():
        h = (encode(encoder, train["obs"])[:, :AGENT_DIM], encode(encoder, test["obs"])[:, :AGENT_DIM])
    return position_r2(h, (train[what], test[what]))


def fit_probe_on(encoder: nn.Module, ef: LatentEgoForesight, data: dict[str, th.Tensor], steps: int) -> None:
    optimizer = th.optim.Adam(ef.decoder.parameters(), lr=3e-3)
    generator = th.Generator().manual_seed(1)
    mask = th.ones(BATCH, HORIZON, dtype=th.bool)
    for _ in range(steps):
        index = th.randint(0, len(data["obs"]), (BATCH,), generator=generator)
        k = ef.draw_steps(mask, generator)
        with th.no_grad():
            h = encode(encoder, data["obs"][index])
        probe_step(ef, optimizer, h, data["actions"][index], k, data["frames"][index, k - 1])


@pytest.mark.slow
def test_latent_ef_puts_the_agent_into_h_a_and_the_probe_saliency_finds_it():
    th.manual_seed(0)
    train, test = collect(60, seed=1), collect(10, seed=2)
    untrained, _ = train_latent(train, 0)
    encoder, ef = train_latent(train, 3000)
    scores = {
        "agent": agent_r2(encoder, train, test, "agent"),
        "distractor": agent_r2(encoder, train, test, "distractor"),
        "untrained agent": agent_r2(untrained, train, test, "agent"),
    }
    assert scores["agent"] > 0.35 and scores["agent"] > scores["untrained agent"] + 0.3, scores
    assert scores["distractor"] < 0.15, scores

    fit_probe_on(encoder, ef, train, 1500)
    ef.eval()
    on_agent, elsewhere = [], []
    with th.no_grad():
        h = encode(encoder, test["obs"][:16])
    for i in range(16):  # saliency of the H-step prediction against where the agent was and went
        h_scene, h_agent = ef.split(h[i : i + 1])
        rolled = ef.rollout(h_agent, test["actions"][i : i + 1])[:, -1]
        agent_map = decoder_saliency(ef, h_scene, rolled).agent
        agent_pixels = (test["agent"][i, 0] | test["agent"][i, 1]).numpy()
        on_agent.append(agent_map[agent_pixels].mean())
        elsewhere.append(agent_map[~agent_pixels].mean())
    assert np.mean(on_agent) > 1.5 * np.mean(elsewhere), (np.mean(on_agent), np.mean(elsewhere), scores)
