"""CURL's loss teaches the encoder to match two crops of one observation: on held-out toy-env observations the
trained encoder picks each query's own key among the batch's far above chance, and above the untrained encoder
(about a minute on 2 busy CPU cores)."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
import torch as th

from sb3_ef.curl import CURLEncoder, CURLLoss
from sb3_ef.envs.toy import ToyAgentEnv

SIZE, CROP, BATCH = 40, 32, 32


class Batch(NamedTuple):
    observations: th.Tensor


def collect(steps: int, seed: int) -> th.Tensor:
    env = ToyAgentEnv(size=SIZE, frame_stack=3)
    rng = np.random.default_rng(seed)
    observation, _ = env.reset(seed=seed)
    observations = [observation]
    while len(observations) < steps:
        observation, _, _, truncated, _ = env.step(rng.uniform(-1, 1, 2))
        if truncated:
            observation, _ = env.reset()
        observations.append(observation)
    return th.as_tensor(np.stack(observations))


def accuracy(loss_fn: CURLLoss, encoder: CURLEncoder, frames: th.Tensor, generator: th.Generator) -> float:
    """Share of queries whose largest logit is their own key, over batches of BATCH held-out observations."""
    hits = 0
    with th.no_grad():
        for start in range(0, len(frames), BATCH):
            queries, keys = loss_fn.prepare(Batch(frames[start : start + BATCH]), pad=0, generator=generator)
            logits = loss_fn.logits(encoder(queries), loss_fn.key_encoder(keys))
            hits += int((logits.argmax(dim=1) == th.arange(len(logits))).sum())
    return hits / len(frames)


@pytest.mark.slow
def test_contrastive_accuracy_rises_far_above_chance():
    train, held_out = collect(2048, seed=0), collect(1024, seed=1)
    # Batches of observations from different episodes: neighbours within an episode are near-duplicates.
    held_out = held_out[th.randperm(len(held_out), generator=th.Generator().manual_seed(2))[:256]]
    encoder = CURLEncoder(ToyAgentEnv(size=SIZE).observation_space, features_dim=32, crop_size=CROP)
    loss_fn = CURLLoss(encoder, CROP, key_update_interval=1)
    generator = th.Generator().manual_seed(0)
    untrained = accuracy(loss_fn, encoder, held_out, th.Generator().manual_seed(1))
    optimizer = th.optim.Adam([*encoder.parameters(), loss_fn.W], lr=1e-3)
    for _ in range(300):
        rows = th.randint(0, len(train), (BATCH,), generator=generator)
        queries, keys = loss_fn.prepare(Batch(train[rows]), pad=0, generator=generator)
        loss, _ = loss_fn(encoder(queries), keys)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        loss_fn.after_update(encoder)
    trained = accuracy(loss_fn, encoder, held_out, th.Generator().manual_seed(1))
    # Chance is 1 / 32 = 0.03.
    assert trained > max(0.25, untrained + 0.2), (trained, untrained)
