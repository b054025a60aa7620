"""SEAR's mask decoder learns where the agent is: on frames of the toy env, trained through a DrQ-v2 encoder, it
predicts the agent masks of held-out observations better than the best mask that ignores the frame (about 2 minutes
on 2 busy CPU cores)."""

from __future__ import annotations

from collections import deque
from typing import NamedTuple

import numpy as np
import pytest
import torch as th

from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.envs.toy import ToyAgentEnv
from sb3_ef.sear import SEARLoss

SIZE, STACK, LATENT = 32, 3, 64


class Batch(NamedTuple):
    """The two fields of a replay batch that SEAR reads."""

    observations: th.Tensor
    masks: th.Tensor


def collect(steps: int, seed: int) -> tuple[th.Tensor, th.Tensor]:
    """Stacked observations and the agent masks of their frames, under random actions."""
    env = ToyAgentEnv(size=SIZE, frame_stack=STACK)
    rng = np.random.default_rng(seed)
    observation, _ = env.reset(seed=seed)
    masks = deque([env.agent_mask()] * STACK, maxlen=STACK)
    observations, stacks = [observation], [np.stack(masks)]
    while len(observations) < steps:
        observation, _, _, truncated, _ = env.step(rng.uniform(-1, 1, 2))
        masks.append(env.agent_mask())
        if truncated:
            observation, _ = env.reset()
            masks.extend([env.agent_mask()] * STACK)
        observations.append(observation)
        stacks.append(np.stack(masks))
    return th.as_tensor(np.stack(observations)), th.as_tensor(np.stack(stacks).astype(np.uint8))


@pytest.mark.slow
def test_mask_decoder_beats_the_best_frame_blind_mask_on_held_out_frames():
    train_frames, train_masks = collect(4096, seed=0)
    test_frames, test_masks = collect(128, seed=1)
    encoder = DrQv2Encoder(ToyAgentEnv(size=SIZE).observation_space, features_dim=LATENT)
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE), coefficients=(0.0, 1.0))  # the mask part alone
    optimizer = th.optim.Adam([*encoder.parameters(), *loss_fn.parameters()], lr=1e-3)
    generator = th.Generator().manual_seed(0)
    for _ in range(400):
        rows = th.randint(0, len(train_frames), (32,), generator=generator)
        observations, targets = loss_fn.prepare(
            Batch(train_frames[rows], train_masks[rows]), pad=2, generator=generator
        )
        loss, _ = loss_fn(encoder(observations), targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()

    with th.no_grad():
        _, probabilities = loss_fn.decode(encoder(test_frames))
    masks = test_masks.float()

    def bce(p: th.Tensor) -> float:
        p = p.clamp(1e-6, 1 - 1e-6)
        return float(-(masks * p.log() + (1 - masks) * (1 - p).log()).flatten(1).sum(1).mean())

    # The frame-blind baseline: each pixel's frequency of being agent in the training masks.
    blind = bce(train_masks.float().mean(dim=0, keepdim=True).expand_as(masks))
    learned = bce(probabilities)
    assert learned < 0.75 * blind, (learned, blind)
