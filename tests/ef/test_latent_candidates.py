"""Latent EF's candidates carry no free answer: a candidate past its episode's end (a zero-filled observation) is left
out of the softmax, and a target view's random shift is drawn apart from the anchor's, so that an encoder which sees
only the shift cannot pick the positive."""

from __future__ import annotations

import math

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn
from torch.nn import functional as F

from sb3_ef.common.buffers import SequenceReplayBuffer
from sb3_ef.ef import foresight_loss
from sb3_ef.ef.latent import info_nce

FEATURES, ACTIONS, AGENT, H, SIZE = 24, 2, 6, 4, 16
LATENT = {"target": "latent", "rollout_hidden_dims": (16,), "decoder_channels": 8, "projection_dim": 8,
          "head_hidden_dim": 16, "step_sampling": "sample"}  # fmt: skip


def conv_encoder() -> nn.Module:
    """A small encoder of 9 x 16 x 16 observations in [0, 1] (fed by :func:`scaled`)."""
    return nn.Sequential(
        nn.Conv2d(9, 16, 3, stride=2, padding=1), nn.ReLU(), nn.Flatten(), nn.Linear(16 * (SIZE // 2) ** 2, FEATURES)
    )  # fmt: skip


def scaled(encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    return encoder(observations.float() / 255.0)


def test_info_nce_leaves_invalid_candidates_out_but_a_samples_own_positive_in():
    prediction, candidates = th.randn(3, 8), th.randn(6, 8)
    valid = th.tensor([True, False, True, True, True, False])
    logits = F.normalize(prediction, dim=1) @ F.normalize(candidates, dim=1).T / 0.1
    kept = [[0, 2, 3, 4], [0, 1, 2, 3, 4], [0, 2, 3, 4]]  # sample 1 keeps its own (invalid) positive
    expected = th.stack([F.cross_entropy(logits[i, kept[i]], th.tensor(kept[i].index(i))) for i in range(3)])
    th.testing.assert_close(info_nce(prediction, candidates, 0.1, valid), expected)


def episodes_buffer(lengths: list[int]) -> SequenceReplayBuffer:
    """A buffer of episodes of the given lengths (shorter than ``H``: every window crosses an episode's end) whose
    frames are random, so that zero-filled steps past an end stand out."""
    observation_space = spaces.Box(0, 255, (9, SIZE, SIZE), np.uint8)
    buffer = SequenceReplayBuffer(200, observation_space, spaces.Box(-1, 1, (ACTIONS,), np.float32), "cpu", horizon=H)
    rng = np.random.default_rng(0)
    for length in lengths:
        frames = rng.integers(1, 256, (length + 3, 3, SIZE, SIZE), dtype=np.uint8)
        for step in range(length):
            obs, next_obs = frames[None, step : step + 3], frames[None, step + 1 : step + 4]
            done = np.array([step == length - 1])
            action = rng.uniform(-1, 1, (1, ACTIONS)).astype(np.float32)
            buffer.add(
                obs.reshape(1, 9, SIZE, SIZE), next_obs.reshape(1, 9, SIZE, SIZE), action, np.zeros(1), done, [{}]
            )
    return buffer


def test_candidates_past_an_episodes_end_do_not_change_the_loss():
    th.manual_seed(0)
    encoder = conv_encoder()
    loss_module = foresight_loss(
        FEATURES, ACTIONS, (3, SIZE, SIZE), AGENT, H, ef_kwargs=LATENT, encoder=encoder, encode=scaled
    )
    batch = episodes_buffer([2, 3, 1, 2, 3, 2]).sample(12)
    observations, targets = loss_module.prepare(batch, pad=0, generator=th.Generator().manual_seed(0))
    valid = targets.candidates_valid()
    candidates = th.cat([targets.observations, targets.negatives])
    assert (~valid).any() and valid.any(), "the batch must hold candidates on both sides of an episode's end"
    assert (candidates[~valid, -3:] == 0).all() and (candidates[valid, -3:] != 0).any()  # newest frame past the end
    features = encoder(observations.float() / 255)
    loss, _ = loss_module(features, targets)

    noise = th.randint(1, 256, candidates.shape, dtype=th.uint8, generator=th.Generator().manual_seed(1))
    candidates = th.where(valid[:, None, None, None], candidates, noise)  # other contents where nothing was
    replaced = targets._replace(observations=candidates[:12], negatives=candidates[12:])
    th.testing.assert_close(loss_module(features, replaced)[0], loss)
    unmasked = loss_module.ef.loss(
        features, targets.actions, targets.steps, loss_module.target_encoder(candidates), targets.valid
    )
    assert not th.allclose(unmasked * loss_module.ef.loss_scale, loss), "the replaced candidates must matter unmasked"


def constant_buffer() -> SequenceReplayBuffer:
    """A buffer whose every frame is one picture, a white square on black: a random shift, which moves the square, is
    the only thing that differs between observations."""
    picture = np.zeros((3, SIZE, SIZE), dtype=np.uint8)
    picture[:, SIZE // 2 - 2 : SIZE // 2 + 2, SIZE // 2 - 2 : SIZE // 2 + 2] = 255
    observation_space = spaces.Box(0, 255, (9, SIZE, SIZE), np.uint8)
    buffer = SequenceReplayBuffer(300, observation_space, spaces.Box(-1, 1, (ACTIONS,), np.float32), "cpu", horizon=H)
    obs = np.tile(picture, (1, 3, 1, 1))
    for step in range(200):
        action = np.full((1, ACTIONS), 0.5, np.float32)
        buffer.add(obs, obs, action, np.zeros(1, np.float32), np.array([step % 50 == 49]), [{}])
    return buffer


def test_an_encoder_that_sees_only_the_shift_cannot_beat_chance():
    """Every observation is the same picture, shifted at random: only the shifts tell candidates apart. Were the
    target views shifted with the anchor, matching shifts would bring the loss far below log(2B) (to about 1.5 after
    these updates); drawn apart, the loss stays at log(2B) = 3.47 within noise."""
    seed = 0
    batch_size, pad = 16, 4
    th.manual_seed(seed)
    encoder = conv_encoder()
    loss_module = foresight_loss(
        FEATURES, ACTIONS, (3, SIZE, SIZE), AGENT, H, ef_kwargs={**LATENT, "target_tau": 1.0}, encoder=encoder,
        encode=scaled,
    )  # fmt: skip
    optimizer = th.optim.Adam([*encoder.parameters(), *loss_module.parameters()], lr=1e-3)
    buffer, generator = constant_buffer(), th.Generator().manual_seed(seed)
    losses = []
    for _ in range(200):
        observations, targets = loss_module.prepare(buffer.sample(batch_size), pad, generator)
        loss, logs = loss_module(encoder(observations.float() / 255), targets)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        loss_module.after_update(encoder)
        losses.append(float(logs["ef_loss"]))
    assert np.mean(losses[-50:]) > math.log(2 * batch_size) - 0.1
