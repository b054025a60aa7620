"""CURLLoss and CURLEncoder: the authors' equations on a fixed batch, which parameters learn, the momentum key
encoder, the crops, save/load and named errors for bad inputs."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from torch import nn
from torch.nn import functional as F

from sb3_ef.curl import CURLEncoder, CURLLoss

B, FRAME, CROP, FEATURES = 5, 24, 20, 6


class Batch(NamedTuple):
    """The field of a replay batch that CURL reads."""

    observations: th.Tensor


def encoder(frame: int = FRAME, crop: int | None = CROP, features: int = FEATURES) -> CURLEncoder:
    return CURLEncoder(spaces.Box(0, 255, (9, frame, frame), np.uint8), features_dim=features, crop_size=crop)


def observations(n: int = B, frame: int = FRAME) -> th.Tensor:
    return th.randint(0, 256, (n, 9, frame, frame), dtype=th.uint8)


def test_loss_follows_the_authors_equations():
    online = encoder()
    loss_fn = CURLLoss(online, CROP)
    queries, keys = loss_fn.prepare(Batch(observations()), pad=4)
    features = online(queries)
    loss, logs = loss_fn(features, keys)

    # MishaLaskin/curl curl_sac.py, written out: z_a W z_pos^T minus the row max, cross-entropy on the diagonal.
    z_pos = loss_fn.key_encoder(keys).detach()
    logits = th.matmul(features, th.matmul(loss_fn.W, z_pos.T))
    logits = logits - th.max(logits, 1)[0][:, None]
    expected = -(logits.diagonal() - th.logsumexp(logits, dim=1)).mean()
    th.testing.assert_close(loss, expected)
    th.testing.assert_close(logs["curl_loss"], expected.detach())
    assert not logs["curl_loss"].requires_grad


def test_w_and_the_online_encoder_learn_the_key_encoder_does_not():
    online = encoder()
    loss_fn = CURLLoss(online, CROP)
    queries, keys = loss_fn.prepare(Batch(observations()), pad=0)
    loss, _ = loss_fn(online(queries), keys)
    loss.backward()
    assert loss_fn.W.grad is not None and loss_fn.W.grad.abs().sum() > 0
    assert all(parameter.grad is not None and parameter.grad.abs().sum() > 0 for parameter in online.parameters())
    assert all(not parameter.requires_grad and parameter.grad is None for parameter in loss_fn.key_encoder.parameters())
    # The loss module's trainable parameters are W alone: the online encoder belongs to the host.
    assert [name for name, parameter in loss_fn.named_parameters() if parameter.requires_grad] == ["W"]


def test_key_encoder_starts_as_a_copy_and_follows_by_tau_every_interval():
    online = encoder()
    loss_fn = CURLLoss(online, CROP, encoder_tau=0.05, key_update_interval=2)
    for key, source in zip(loss_fn.key_encoder.parameters(), online.parameters(), strict=True):
        assert th.equal(key, source) and key.data_ptr() != source.data_ptr()
    with th.no_grad():
        for parameter in online.parameters():
            parameter.add_(th.randn_like(parameter))
    before = [parameter.clone() for parameter in loss_fn.key_encoder.parameters()]
    loss_fn.after_update(online)  # first call: not yet (CURL moves it with the critic target, every 2 updates)
    assert all(th.equal(key, old) for key, old in zip(loss_fn.key_encoder.parameters(), before, strict=True))
    loss_fn.after_update(online)
    for key, old, source in zip(loss_fn.key_encoder.parameters(), before, online.parameters(), strict=True):
        th.testing.assert_close(key, 0.95 * old + 0.05 * source)


def test_crops_are_two_independent_windows_of_each_observation():
    loss_fn = CURLLoss(encoder(), CROP)
    frames = observations(n=16)
    queries, keys = loss_fn.prepare(Batch(frames), pad=4, generator=th.Generator().manual_seed(0))
    assert queries.shape == keys.shape == (16, 9, CROP, CROP)

    def corner(crop: th.Tensor, frame: th.Tensor) -> tuple[int, int]:
        found = [
            (top, left)
            for top in range(FRAME - CROP + 1)
            for left in range(FRAME - CROP + 1)
            if th.equal(frame[:, top : top + CROP, left : left + CROP], crop)
        ]
        assert len(found) == 1
        return found[0]

    corners = [(corner(q, f), corner(k, f)) for q, k, f in zip(queries, keys, frames, strict=True)]
    assert any(query != key for query, key in corners)
    # The authors' offsets: randint(0, FRAME - CROP), never the last window that fits.
    assert all(max(offset) < FRAME - CROP for pair in corners for offset in pair)


def test_encoder_has_the_authors_layers_and_centre_crops_larger_frames():
    online = CURLEncoder(spaces.Box(0, 255, (9, 100, 100), np.uint8), crop_size=84)
    convs = [module for module in online.convnet if isinstance(module, nn.Conv2d)]
    assert [(conv.in_channels, conv.out_channels, conv.kernel_size, conv.stride) for conv in convs] == [
        (9, 32, (3, 3), (2, 2)),
        *[(32, 32, (3, 3), (1, 1))] * 3,
    ]
    linear, norm = online.projection
    assert (linear.in_features, linear.out_features, norm.normalized_shape) == (32 * 35 * 35, 50, (50,))
    # Delta-orthogonal init: only the centre tap of each kernel is non-zero.
    assert th.count_nonzero(convs[1].weight[:, :, [0, 0, 2, 2], [0, 2, 0, 2]]) == 0
    frames = observations(n=2, frame=100)
    centre = frames[:, :, 8:92, 8:92]
    th.testing.assert_close(online(frames), online(centre))
    # Images are scaled by 1 / 255 only (no -0.5 shift), as in the authors' encoder.
    first = convs[0](centre.float() / 255.0)
    th.testing.assert_close(online.convnet[:2](centre.float() / 255.0), th.relu(first))


def test_a_hosts_key_encoder_is_used_as_it_is_neither_saved_nor_moved_here():
    online, target = encoder(), encoder()
    loss_fn = CURLLoss(online, CROP, key_encoder=target)
    assert loss_fn.key_encoder is target and not loss_fn.owns_key_encoder
    assert set(loss_fn.state_dict()) == {"W", "updates"}
    assert [name for name, _ in loss_fn.named_parameters()] == ["W"]
    queries, keys = loss_fn.prepare(Batch(observations()), pad=0)
    loss, _ = loss_fn(online(queries), keys)
    logits = loss_fn.logits(online(queries), target(keys))
    th.testing.assert_close(loss, F.cross_entropy(logits, th.arange(B)))
    before = [parameter.clone() for parameter in target.parameters()]
    for _ in range(2):
        loss_fn.after_update(online)
    assert all(th.equal(old, new) for old, new in zip(before, target.parameters(), strict=True))
    assert int(loss_fn.updates) == 2
    with pytest.raises(ValueError, match=r"a given key_encoder is moved by its host, got encoder_tau=0\.1"):
        CURLLoss(online, CROP, key_encoder=target, encoder_tau=0.1)


def test_state_dict_holds_tensors_only():
    loss_fn = CURLLoss(encoder(), CROP)
    loss_fn.after_update(encoder())
    state = loss_fn.state_dict()
    assert all(isinstance(value, th.Tensor) for value in state.values())
    assert state["updates"].dtype == th.long and int(state["updates"]) == 1


def test_an_encoder_sharing_anothers_convolutions_trains_only_its_linear_layer_and_layer_norm():
    critic, actor = encoder(), encoder()
    actor.share_convolutions(critic)  # the authors' copy_conv_weights_from, with detach_encoder=True
    assert actor.convnet is critic.convnet and actor.projection is not critic.projection
    actor(observations(frame=CROP)).sum().backward()
    assert all(parameter.grad is None for parameter in critic.convnet.parameters())
    assert all(parameter.grad is not None for parameter in actor.projection.parameters())
    with pytest.raises(ValueError, match="same layers and filters"):
        space = spaces.Box(0, 255, (9, FRAME, FRAME), np.uint8)
        encoder().share_convolutions(CURLEncoder(space, features_dim=FEATURES, crop_size=CROP, n_filters=8))


def test_state_dict_round_trip_keeps_w_the_key_encoder_and_the_update_phase():
    online = encoder()
    loss_fn = CURLLoss(online, CROP, key_update_interval=2)
    loss_fn.after_update(online)
    restored = CURLLoss(encoder(), CROP, key_update_interval=2)
    restored.load_state_dict(loss_fn.state_dict())
    assert th.equal(restored.W, loss_fn.W)
    before = [parameter.clone() for parameter in restored.key_encoder.parameters()]
    restored.after_update(online)  # second call after the saved first one: the key encoder moves
    assert not all(th.equal(key, old) for key, old in zip(restored.key_encoder.parameters(), before, strict=True))


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: CURLLoss(encoder(), FRAME + 1), r"crop_size must be an int in \[1, 24\].*24x24.*got 25"),
        (lambda: CURLLoss(nn.Linear(3, 3), CROP), r"features extractor"),
        (lambda: CURLLoss(encoder(), CROP, key_encoder=nn.Linear(3, 3)), r"key_encoder must be a features extractor"),
        (lambda: CURLLoss(encoder(), CROP, encoder_tau=0.0), r"encoder_tau must be in \(0, 1\]"),
        (lambda: CURLLoss(encoder(), CROP, key_update_interval=0), r"key_update_interval must be a positive int"),
        (lambda: encoder(crop=FRAME + 1), r"crop_size must be an int in \[1, 24\].*got 25"),
        (lambda: encoder(crop=14), r"too small for 4 convolutions"),
        (lambda: encoder(features=0), r"features_dim must be a positive int"),
    ],
)
def test_bad_arguments_are_refused_with_the_cause_named(build, message):
    with pytest.raises(ValueError, match=message):
        build()


def test_frames_smaller_than_the_crop_and_features_of_the_wrong_width_are_refused():
    loss_fn = CURLLoss(encoder(), CROP)
    with pytest.raises(ValueError, match=r"crops 20x20 windows.*got observations of shape \(5, 9, 16, 16\)"):
        loss_fn.prepare(Batch(observations(frame=16)), pad=0)
    with pytest.raises(ValueError, match=r"features of shape \(batch, 6\), got \(5, 7\)"):
        loss_fn(th.randn(B, 7), observations(frame=CROP))
