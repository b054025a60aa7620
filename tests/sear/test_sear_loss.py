"""SEARLoss: the authors' equations on a fixed batch, their networks' shapes, which parameters each part trains,
one shift for frames and masks, and named errors for bad inputs."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.sear import SEAR_COEFFICIENTS, SEARLoss, SEARTargets

B, STACK, SIZE, LATENT = 3, 2, 24, 10


class MaskedBatch(NamedTuple):
    """The two fields of a replay batch that SEAR reads."""

    observations: th.Tensor
    masks: th.Tensor


def batch(size: int = SIZE, stack: int = STACK, n: int = B) -> MaskedBatch:
    frames = th.randint(0, 256, (n, 3 * stack, size, size), dtype=th.uint8)
    # Each frame's mask marks its bright red pixels, so a mask can be checked against its frame after a shift.
    masks = (frames[:, 0::3] > 127).to(th.uint8)
    return MaskedBatch(frames, masks)


@pytest.mark.parametrize("preset", sorted(SEAR_COEFFICIENTS))
def test_loss_follows_the_authors_equations(preset):
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE), coefficients=preset)
    data = batch()
    features = th.randn(B, LATENT)
    loss, logs = loss_fn(features, SEARTargets(data.observations, data.masks))

    # sear-rl sear/agents/sear.py, written out: the first half decodes frames, the second masks.
    first, second = features[:, : LATENT // 2], features[:, LATENT // 2 :]
    decoded = th.clamp(loss_fn.frame_decoder(first), -0.5, 0.5)
    target = data.observations.float() / 255.0 - 0.5
    reconstruction = ((decoded - target) ** 2).reshape(B, -1).sum(dim=1).mean()
    probabilities = th.sigmoid(loss_fn.mask_decoder(second))
    masks = data.masks.float()
    bce = -(masks * th.log(probabilities).clamp(min=-100) + (1 - masks) * th.log(1 - probabilities).clamp(min=-100))
    mask = bce.reshape(B, -1).sum(dim=1).mean()
    reconstruction_coef, mask_coef = {"sear": (1.0, 0.25), "efrl": (0.01, 0.0025)}[preset]

    th.testing.assert_close(logs["reconstruction_loss"], reconstruction.detach())
    th.testing.assert_close(logs["mask_loss"], mask.detach())
    th.testing.assert_close(loss, reconstruction_coef * reconstruction + mask_coef * mask)
    assert not logs["mask_loss"].requires_grad and loss.requires_grad


def test_explicit_coefficients_weight_the_parts():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE), coefficients=(2.0, 0.5))
    data = batch()
    loss, logs = loss_fn(th.randn(B, LATENT), SEARTargets(*data))
    th.testing.assert_close(loss.detach(), 2.0 * logs["reconstruction_loss"] + 0.5 * logs["mask_loss"])


def _authors_pool_decoder(in_dim: int, out_channels: int) -> nn.ModuleDict:
    """sear-rl sear/models/decoder.py PoolDecoder(in_channels=16, ...), layer for layer."""
    return nn.ModuleDict(
        {
            "projection": nn.Sequential(nn.Linear(in_dim, 16 * 8 * 8), nn.ReLU()),
            "transpose_convnet": nn.Sequential(
                nn.ConvTranspose2d(16, 16, 4, 4, 0, 3), nn.ReLU(),
                nn.ConvTranspose2d(16, 32, 3, 1), nn.ReLU(),
                nn.ConvTranspose2d(32, 32, 3, 1), nn.ReLU(),
                nn.ConvTranspose2d(32, 32, 3, 1), nn.ReLU(),
                nn.ConvTranspose2d(32, out_channels, 3, 2, 0, 1),
            ),
        }
    )  # fmt: skip


def test_decoders_are_the_authors_pool_decoders_at_84():
    loss_fn = SEARLoss(4096, (9, 84, 84))
    latent = th.randn(2, 2048)
    for decoder, out_channels in ((loss_fn.frame_decoder, 9), (loss_fn.mask_decoder, 3)):
        authors = _authors_pool_decoder(2048, out_channels)
        state = {key.replace("deconvs.", "transpose_convnet."): value for key, value in decoder.state_dict().items()}
        authors.load_state_dict(state)  # strict: every layer has the authors' shape
        expected = authors["transpose_convnet"](authors["projection"](latent).view(2, 16, 8, 8))
        assert expected.shape == (2, out_channels, 84, 84)
        th.testing.assert_close(decoder(latent), expected)


def test_sears_encoder_is_the_pooled_drqv2_encoder_with_a_4096_latent():
    """sear-rl's PoolEncoder(repr_dim=4096) equals DrQv2Encoder(features_dim=4096), weights and outputs."""
    encoder = DrQv2Encoder(spaces.Box(0, 255, (9, 84, 84), np.uint8), features_dim=4096)
    authors = nn.ModuleDict(
        {
            "convnet": nn.Sequential(
                nn.Conv2d(9, 32, 3, stride=2), nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=1), nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=1), nn.ReLU(),
                nn.Conv2d(32, 32, 3, stride=1), nn.ReLU(),
                nn.AvgPool2d(4, stride=4),
            ),
            "projection": nn.Sequential(nn.Linear(32 * 8 * 8, 4096)),
        }
    )  # fmt: skip
    state = {key.replace("projection.2.", "projection.0."): value for key, value in encoder.state_dict().items()}
    authors.load_state_dict(state)
    observations = th.randint(0, 256, (2, 9, 84, 84), dtype=th.uint8)
    expected = authors["projection"](authors["convnet"](observations / 255.0 - 0.5).view(2, -1))
    th.testing.assert_close(encoder(observations), expected)


def _grads(module: nn.Module) -> list[th.Tensor | None]:
    return [parameter.grad for parameter in module.parameters()]


@pytest.mark.parametrize("part", ["reconstruction", "mask"])
def test_each_part_trains_only_its_half_of_the_latent_and_its_decoder(part):
    coefficients = (1.0, 0.0) if part == "reconstruction" else (0.0, 1.0)
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE), coefficients=coefficients)
    features = th.randn(B, LATENT, requires_grad=True)
    loss, _ = loss_fn(features, SEARTargets(*batch()))
    loss.backward()
    half = LATENT // 2
    used, unused = (
        (slice(0, half), slice(half, None)) if part == "reconstruction" else (slice(half, None), slice(0, half))
    )
    assert features.grad[:, used].abs().sum() > 0
    assert th.count_nonzero(features.grad[:, unused]) == 0
    trained, untouched = (
        (loss_fn.frame_decoder, loss_fn.mask_decoder)
        if part == "reconstruction"
        else (loss_fn.mask_decoder, loss_fn.frame_decoder)
    )
    assert any(grad is not None and grad.abs().sum() > 0 for grad in _grads(trained))
    assert all(grad is None or th.count_nonzero(grad) == 0 for grad in _grads(untouched))


def test_both_parts_reach_the_encoder():
    encoder = DrQv2Encoder(spaces.Box(0, 255, (3 * STACK, SIZE, SIZE), np.uint8), features_dim=LATENT)
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    observations, targets = loss_fn.prepare(batch(), pad=2)
    loss, _ = loss_fn(encoder(observations), targets)
    loss.backward()
    assert all(parameter.grad is not None and parameter.grad.abs().sum() > 0 for parameter in encoder.parameters())


def test_frames_and_masks_share_one_shift():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    data = batch(n=8)
    observations, targets = loss_fn.prepare(data, pad=4, generator=th.Generator().manual_seed(3))
    assert th.equal(targets.frames, observations)
    assert not th.equal(observations, data.observations)  # shifted
    # The masks moved with their frames: each still marks its own frame's bright red pixels.
    assert th.equal(targets.masks, (observations[:, 0::3] > 127).to(th.uint8))
    # The shift is DrQ's random shift (replicate padding, integer offsets in [-pad, pad]).
    (expected,) = random_shift(data.observations, pad=4, generator=th.Generator().manual_seed(3))
    assert th.equal(observations, expected)


def test_decode_gives_frames_in_range_and_mask_probabilities():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    frames, masks = loss_fn.decode(th.randn(B, LATENT) * 50)
    assert frames.shape == (B, 3 * STACK, SIZE, SIZE) and masks.shape == (B, STACK, SIZE, SIZE)
    assert frames.min() >= -0.5 and frames.max() <= 0.5 and masks.min() >= 0 and masks.max() <= 1


def test_missing_masks_are_refused_with_the_fix_named():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    fields = {name: th.zeros(1) for name in SequenceReplayBufferSamples._fields}
    fields["observations"] = batch().observations
    if "masks" in fields:
        fields["masks"] = None
    with pytest.raises(ValueError, match=r"agent mask.*agent_masks=True.*store_masks=True"):
        loss_fn.prepare(SequenceReplayBufferSamples(**fields), pad=4)


@pytest.mark.parametrize(
    ("masks_shape", "observations_shape"),
    [((B, STACK + 1, SIZE, SIZE), (B, 3 * STACK, SIZE, SIZE)), ((B, STACK, SIZE, SIZE), (B, 3 * STACK, SIZE, 30))],
)
def test_masks_or_observations_of_the_wrong_shape_are_refused(masks_shape, observations_shape):
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    data = MaskedBatch(th.zeros(observations_shape, dtype=th.uint8), th.zeros(masks_shape, dtype=th.uint8))
    with pytest.raises(ValueError, match=r"SEAR expects observations \(batch, 6, 24, 24\) and masks \(3, 2, 24, 24\)"):
        loss_fn.prepare(data, pad=4)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"features_dim": 4095}, r"halves: features_dim must be an even int >= 2, got 4095"),
        ({"features_dim": True}, r"even int"),
        ({"observation_shape": (8, SIZE, SIZE)}, r"\(3 \* frame_stack, height, width\), got \(8, 24, 24\)"),
        ({"observation_shape": (6, 20, 20)}, r"at least 21x21.*got 20x20"),
        ({"coefficients": "drqv2"}, r"Unknown SEAR coefficient preset 'drqv2': expected one of \['efrl', 'sear'\]"),
        ({"coefficients": (1.0,)}, r"pair of non-negative numbers"),
        ({"coefficients": (1.0, -0.25)}, r"pair of non-negative numbers"),
    ],
)
def test_bad_arguments_are_refused_with_the_cause_named(kwargs, message):
    arguments = {"features_dim": LATENT, "observation_shape": (3 * STACK, SIZE, SIZE), **kwargs}
    with pytest.raises(ValueError, match=message):
        SEARLoss(**arguments)


def test_features_of_the_wrong_width_are_refused():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    with pytest.raises(ValueError, match=r"features of shape \(batch, 10\), got \(3, 12\)"):
        loss_fn(th.randn(B, 12), SEARTargets(*batch()))


def test_state_dict_round_trip_restores_the_loss_exactly():
    loss_fn = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    other = SEARLoss(LATENT, (3 * STACK, SIZE, SIZE))
    other.load_state_dict(loss_fn.state_dict())
    features, targets = th.randn(B, LATENT), SEARTargets(*batch())
    assert th.equal(loss_fn(features, targets)[0], other(features, targets)[0])
