"""Ego-Foresight learns to foresee the agent, not the distractor, in the toy pixel world.

A red square moves by the actions, a green square on a random walk that ignores them. After training a small
encoder with EF on babbling data, the open-loop prediction H steps ahead must (1) show the agent far better than
copying the last context frame, (2) move the agent where the actions take it, and (3) not move the distractor
towards where it truly went. Baselines that must fail the same criteria: the untrained model, and the trained
model fed the actions of other samples.
"""

from __future__ import annotations

import pytest
import torch as th
from torch import nn

from sb3_ef.ef import EgoForesight
from tests.helpers.learning import toy_babbling_windows

HORIZON = 4
EPISODE = 30
RED, GREEN = 0, 1


def collect_windows(size: int, episodes: int, seed: int) -> dict[str, th.Tensor]:
    """Every full EF window of toy-world babbling episodes (masks of steps t .. t + H)."""
    return toy_babbling_windows(size, episodes, seed, HORIZON, EPISODE)


def make_model(size: int) -> tuple[nn.Module, EgoForesight]:
    encoder = nn.Sequential(
        nn.Conv2d(9, 16, 3, stride=2, padding=1), nn.ReLU(),
        nn.Conv2d(16, 32, 3, stride=2, padding=1), nn.ReLU(),
        nn.Flatten(), nn.Linear(32 * (size // 4) ** 2, 64),
    )  # fmt: skip
    ef = EgoForesight(
        64, 2, (3, size, size), agent_dim=8, horizon=HORIZON, rollout_hidden_dims=(64, 64), decoder_channels=32,
        step_sampling="sample",
    )  # fmt: skip
    return encoder, ef


def encode(encoder: nn.Module, obs: th.Tensor) -> th.Tensor:
    return encoder(obs.float() / 255 - 0.5)


def train(encoder: nn.Module, ef: EgoForesight, data: dict[str, th.Tensor], updates: int, batch_size: int = 32):
    """The hosts' EF update without the RL loss: draw k, take the frame at k, minimise ``ef.loss``."""
    optimizer = th.optim.Adam([*encoder.parameters(), *ef.parameters()], lr=3e-3)
    generator = th.Generator().manual_seed(0)
    mask = th.ones(batch_size, HORIZON, dtype=th.bool)
    for _ in range(updates):
        index = th.randint(0, len(data["obs"]), (batch_size,), generator=generator)
        steps = ef.draw_steps(mask, generator)
        target = data["frames"][index, steps - 1]
        loss = ef.loss(encode(encoder, data["obs"][index]), data["actions"][index], steps, target)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()


def follow_score(predicted: th.Tensor, masks: th.Tensor) -> float:
    """Mean predicted intensity where the square arrived minus where it left (> 0: the prediction moved it)."""
    arrived, left = (masks[:, -1] & ~masks[:, 0]).float(), (masks[:, 0] & ~masks[:, -1]).float()
    moved = (arrived.sum((1, 2)) > 0) & (left.sum((1, 2)) > 0)
    at_arrival = (predicted * arrived).sum((1, 2)) / arrived.sum((1, 2)).clamp(min=1)
    at_departure = (predicted * left).sum((1, 2)) / left.sum((1, 2)).clamp(min=1)
    return float((at_arrival - at_departure)[moved].mean())


@th.no_grad()
def evaluate(encoder: nn.Module, ef: EgoForesight, data: dict[str, th.Tensor], shuffle_actions: bool = False):
    """Agent error of the H-step prediction relative to copying, and how far agent / distractor are followed."""
    encoder.eval()
    ef.eval()
    actions = data["actions"]
    if shuffle_actions:
        actions = actions[th.randperm(len(actions), generator=th.Generator().manual_seed(1))]
    predicted = ef.predict(encode(encoder, data["obs"]), actions)[:, -1]
    encoder.train()
    ef.train()
    target, last_context = data["frames"][:, -1].float() / 255, data["obs"][:, -3:].float() / 255
    agent_pixels = (data["agent"][:, 0] | data["agent"][:, -1]).float()

    def agent_error(frames: th.Tensor) -> float:
        return float(((frames - target).pow(2).sum(1) * agent_pixels).sum() / agent_pixels.sum())

    return {
        "agent_error_vs_copy": agent_error(predicted) / agent_error(last_context),
        "agent_follow": follow_score(predicted[:, RED], data["agent"]),
        "distractor_follow": follow_score(predicted[:, GREEN], data["distractor"] & ~data["agent"][:, -1:]),
    }


def learned_agent(metrics: dict[str, float], max_error: float, min_follow: float) -> bool:
    return metrics["agent_error_vs_copy"] < max_error and metrics["agent_follow"] > min_follow


def check_learns(size: int, updates: int, max_error: float, min_follow: float) -> None:
    th.manual_seed(0)
    train_data, test_data = collect_windows(size, 60, seed=1), collect_windows(size, 10, seed=2)
    encoder, ef = make_model(size)
    untrained = evaluate(encoder, ef, test_data)
    train(encoder, ef, train_data, updates)
    trained = evaluate(encoder, ef, test_data)
    shuffled = evaluate(encoder, ef, test_data, shuffle_actions=True)
    report = f"untrained {untrained}, trained {trained}, shuffled actions {shuffled}"

    assert learned_agent(trained, max_error, min_follow), report
    assert not learned_agent(untrained, max_error, min_follow), report
    assert not learned_agent(shuffled, max_error, min_follow), report
    assert trained["distractor_follow"] < 0.05, report


def test_ef_foresees_the_agent_and_not_the_distractor():
    check_learns(size=16, updates=800, max_error=0.5, min_follow=0.15)


@pytest.mark.slow
def test_ef_foresees_the_agent_and_not_the_distractor_at_32_pixels():
    check_learns(size=32, updates=1500, max_error=0.45, min_follow=0.25)
