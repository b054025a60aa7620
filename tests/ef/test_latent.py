"""The pieces of latent Ego-Foresight: the stacked observation at t+k, the other step k', the InfoNCE, the momentum
target encoder (parameters as buffers), the probe, and the checks of ``ef_kwargs``."""

from __future__ import annotations

import pytest
import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ef.auxiliary.momentum import momentum_copy
from sb3_ef.ef import EgoForesight, ForesightLoss, ego_foresight, foresight_loss
from sb3_ef.ef.latent import (
    MomentumTarget,
    draw_other_steps,
    info_nce,
    stacked_observations_at,
)
from sb3_ef.ef.probe import probe_step

B, FEATURES, ACTIONS, AGENT, H, STACK = 5, 24, 2, 6, 4, 3
LATENT = {"target": "latent", "rollout_hidden_dims": (16,), "decoder_channels": 8, "projection_dim": 8,
          "head_hidden_dim": 16}  # fmt: skip


def make_ef(**kwargs) -> EgoForesight:
    return ego_foresight(FEATURES, ACTIONS, (3, 16, 16), agent_dim=AGENT, horizon=H, **{**LATENT, **kwargs})


def window() -> tuple[th.Tensor, th.Tensor]:
    """Observations at t and future frames whose every pixel is the frame's time t-2 .. t+H (as 10 + time)."""
    times = th.arange(-STACK + 1, H + 1) + 10
    frames = times[None, :, None, None, None].expand(B, -1, 3, 16, 16).to(th.uint8)
    return frames[:, :STACK].flatten(1, 2).contiguous(), frames[:, STACK:].contiguous()


def test_the_stacked_observation_at_t_plus_k_holds_frames_t_plus_k_minus_2_to_t_plus_k():
    observations, future = window()
    steps = th.tensor([1, 2, 3, 4, 2])
    stacked = stacked_observations_at(observations, future, steps)
    assert stacked.shape == observations.shape and stacked.dtype == th.uint8
    times = stacked.unflatten(1, (STACK, 3))[:, :, 0, 0, 0].long() - 10
    assert th.equal(times, steps[:, None] + th.arange(-STACK + 1, 1))
    with pytest.raises(ValueError, match=r"future_frames \(batch, H, C, h, w\)"):
        stacked_observations_at(observations, future[:, :, :, :8], steps)


def test_the_other_step_differs_from_k_and_is_valid_where_one_is():
    mask = th.ones(B, H, dtype=th.bool)
    mask[0, 2:] = False  # sample 0: steps 1, 2 valid
    mask[1, 1:] = False  # sample 1: only step 1 valid, its k
    steps = th.tensor([1, 1, 3, 4, 2])
    generator = th.Generator().manual_seed(0)
    for _ in range(50):
        others = draw_other_steps(mask, steps, H, generator)
        assert others is not None and not (others == steps).any()
        assert (others >= 1).all() and (others <= H).all()
        assert others[0] == 2  # its one other valid step
    assert draw_other_steps(mask[:, :1], steps.clamp(max=1), 1) is None


def test_info_nce_is_the_cross_entropy_of_the_cosine_logits():
    prediction, candidates = th.randn(B, 8), th.randn(2 * B, 8)
    logits = F.normalize(prediction, dim=1) @ F.normalize(candidates, dim=1).T / 0.1
    expected = F.cross_entropy(logits, th.arange(B), reduction="none")
    th.testing.assert_close(info_nce(prediction, candidates, 0.1), expected)


def test_latent_loss_predicts_from_the_rolled_out_agent_and_the_scene_features():
    ef = make_ef()
    h, actions, steps = th.randn(B, FEATURES), th.randn(B, H, ACTIONS), th.tensor([1, 2, 3, 4, 4])
    candidates = th.randn(2 * B, 8)
    valid = th.tensor([True, True, False, True, True])
    rolled = ef.rollout(h[:, :AGENT], actions)[th.arange(B), steps - 1]
    per_sample = info_nce(ef.head(th.cat([rolled, h[:, AGENT:]], dim=1)), candidates, ef.head.temperature)
    expected = per_sample[valid].mean()
    th.testing.assert_close(ef.loss(h, actions, steps, candidates, valid), expected)
    with pytest.raises(ValueError, match=r"target features of shape \(>= 5, 8\)"):
        ef.loss(h, actions, steps, candidates[:3], valid)
    with pytest.raises(ValueError, match=r"target features of shape \(>= 5, 8\)"):  # a frame is not its target
        ef.loss(h, actions, steps, th.zeros(B, 3, 16, 16, dtype=th.uint8))


def test_the_momentum_copy_keeps_its_weights_as_buffers_out_of_every_optimiser():
    online = nn.Sequential(nn.Linear(4, 3), nn.BatchNorm1d(3))
    copied = momentum_copy(online)
    assert list(copied.parameters()) == [] and not copied.training
    copied_state, online_state = copied.state_dict(), online.state_dict()
    assert copied_state.keys() == online_state.keys()
    assert all(th.equal(copied_state[name], online_state[name]) for name in online_state)
    assert not any(tensor.requires_grad for tensor in copied.buffers())
    x = th.randn(6, 4)
    online.eval()
    assert th.equal(copied(x), online(x))


def test_the_target_moves_by_tau_and_copies_the_online_buffers():
    online, projection = nn.Sequential(nn.Linear(4, 3), nn.BatchNorm1d(3)), nn.Linear(3, 2)
    target = MomentumTarget(online, projection, tau=0.25)
    target.train()
    assert not target.encoder.training  # stays in eval mode
    with th.no_grad():
        for parameter in [*online.parameters(), *projection.parameters()]:
            parameter.add_(1.0)
    online.train()
    online(th.randn(8, 4))  # moves the batch-norm statistics
    old = [b.clone() for b in target.encoder.buffers()]
    target.update(online, projection)
    weight = target.encoder.get_buffer("0.weight")
    th.testing.assert_close(weight, 0.75 * old[0] + 0.25 * online[0].weight)
    assert th.equal(target.encoder.get_buffer("1.running_mean"), online[1].running_mean)
    with pytest.raises(ValueError, match="pass the encoder the copy was built from"):
        target.update(nn.Linear(4, 3), projection)
    with pytest.raises(ValueError, match=r"target_tau must be a number in \(0, 1\], got 0"):
        MomentumTarget(online, projection, tau=0)


@pytest.mark.parametrize(
    ("ef_kwargs", "message"),
    [
        ({"target": "frames"}, r"ef_kwargs target must be one of \('pixel', 'latent'\), got str 'frames'"),
        ({"target": None}, r"must be one of \('pixel', 'latent'\), got None"),
        ({"projection_dim": 8}, r"\['projection_dim'\] apply to target='latent' only"),
        ({"temperature": 0.2, "head_hidden_dim": 8}, r"\['temperature', 'head_hidden_dim'\] apply to target='latent'"),
        ({"target_tau": 0.1}, r"\['target_tau'\] apply to target='latent' only"),
        ({"target": "latent", "decode_batch_size": 4}, r"\['decode_batch_size'\] apply to target='pixel' only"),
        ({"target": "latent", "temperature": 0}, "temperature must be a finite positive number, got 0"),
        ({"target": "latent", "temperature": float("inf")}, "temperature must be a finite positive number, got inf"),
        ({"target": "latent", "temperature": float("nan")}, "temperature must be a finite positive number, got nan"),
        ({"target": "latent", "temperature": -0.1}, r"temperature must be a finite positive number, got -0.1"),
        ({"target": "latent", "loss_scale": float("inf")}, "loss_scale must be a finite number >= 0, got inf"),
        ({"loss_scale": 2.0}, r"\['loss_scale'\] apply to target='latent' only"),
        ({"target": "latent", "projection_dim": 0}, "projection_dim must be a positive integer, got 0"),
        ({"target": "latent", "target_tau": 1.5}, r"target_tau must be a number in \(0, 1\], got 1.5"),
    ],
)
def test_bad_ef_kwargs_are_named(ef_kwargs, message):
    with pytest.raises(ValueError, match=message):
        foresight_loss(FEATURES, ACTIONS, (3, 16, 16), AGENT, H, ef_kwargs=ef_kwargs, encoder=nn.Linear(2, FEATURES))


def test_latent_ef_needs_the_hosts_encoder_and_pixel_ef_keeps_its_modules():
    with pytest.raises(ValueError, match="predicts the features of the host's encoder: pass encoder="):
        foresight_loss(FEATURES, ACTIONS, (3, 16, 16), AGENT, H, ef_kwargs={"target": "latent"})
    pixel = ForesightLoss(FEATURES, ACTIONS, (3, 16, 16), AGENT, H, ef_kwargs={"target": "pixel"})
    assert not hasattr(pixel, "target_encoder") and not hasattr(pixel.ef, "head")
    assert all(name.startswith(("ef.rollout_block.", "ef.decoder.")) for name in pixel.state_dict() if name != "beta")


def test_the_probe_trains_the_decoder_alone_and_decoding_waits_for_it():
    ef = make_ef()
    h, actions, steps = th.randn(B, FEATURES, requires_grad=True), th.randn(B, H, ACTIONS), th.full((B,), 2)
    frames = th.randint(0, 256, (B, 3, 16, 16), dtype=th.uint8)
    with pytest.raises(ValueError, match="not trained yet; fit it first"):
        ef.decode(h[:, AGENT:], h[:, :AGENT])
    with pytest.raises(ValueError, match=r"optimizer must hold ef\.decoder's parameters only"):
        probe_step(ef, th.optim.Adam(ef.parameters()), h, actions, steps, frames)
    before = {name: tensor.clone() for name, tensor in ef.state_dict().items()}
    probe_step(ef, th.optim.Adam(ef.decoder.parameters(), lr=1e-2), h, actions, steps, frames)
    changed = {name for name, tensor in ef.state_dict().items() if not th.equal(tensor, before[name])}
    assert changed and all(name.startswith("decoder.") or name == "probe_steps" for name in changed)
    assert h.grad is None and all(p.grad is None for p in ef.parameters())
    assert ef.decode(h[:, AGENT:], h[:, :AGENT]).shape == (B, 3, 16, 16)
