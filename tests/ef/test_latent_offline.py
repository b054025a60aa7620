"""Latent Ego-Foresight in offline ``pretrain``: the target encoder is built, saved and followed by momentum, the probe
decoder learns alongside so that the held-out evaluation (frames, saliency) works, and a resumed run continues both."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch as th

from sb3_ef.cli import main
from sb3_ef.ef.latent import MomentumTarget
from sb3_ef.offline.model import OfflineEF, load_pretrained
from sb3_ef.offline.pretrain import CHECKPOINT, METRICS, MODEL, pretrain
from tests.helpers.offline import TINY_DRQV2, square_episode

LATENT = {"target": "latent", "rollout_hidden_dims": (16,), "decoder_channels": 8, "projection_dim": 8,
          "head_hidden_dim": 16}  # fmt: skip
ARGUMENTS = dict(horizon=3, batch_size=4, holdout=1, eval_every=100, saliency_windows=2, progress_bar=False,
                 tensorboard=False, **TINY_DRQV2)  # fmt: skip


def episodes() -> list:
    return [square_episode(steps=12, size=32, seed=seed) for seed in range(3)]


@pytest.mark.parametrize("encoder", ["drqv2", "dcgan-unet"])
def test_latent_pretraining_trains_the_target_by_momentum_and_the_probe_alongside(encoder, tmp_path):
    size = 64 if encoder == "dcgan-unet" else 32
    data = [square_episode(steps=12, size=size, seed=seed) for seed in range(3)]
    encoder_kwargs = {} if encoder == "dcgan-unet" else {"features_dim": 64}
    arguments = {**ARGUMENTS, "encoder": encoder, "encoder_kwargs": encoder_kwargs}
    model, scores = pretrain(data, tmp_path, steps=3, ef_kwargs=LATENT, seed=0, **arguments)
    assert isinstance(model.target_encoder, MomentumTarget) and int(model.ef.probe_steps) == 3
    metrics = json.loads((tmp_path / METRICS).read_text())
    assert {"frame_ratio", "agent_ratio", "saliency_precision"} <= metrics.keys()
    assert np.isfinite(scores["agent_ratio"])
    th.manual_seed(0)  # pretrain's seed: the model as it was built
    initial = OfflineEF(model.config).target_encoder
    assert initial is not None
    target, start = model.target_encoder.state_dict(), initial.state_dict()
    assert any(not th.equal(target[name], start[name]) for name in start)
    loaded, _ = load_pretrained(tmp_path / MODEL)
    for name, tensor in model.state_dict().items():
        assert th.equal(tensor, loaded.state_dict()[name]), name


def test_resumed_latent_pretraining_continues_from_the_checkpoints_target_and_probe(tmp_path):
    data = episodes()
    first, _ = pretrain(data, tmp_path, steps=2, checkpoint_every=2, ef_kwargs=LATENT, **ARGUMENTS)
    saved, _ = load_pretrained(tmp_path / CHECKPOINT)
    assert saved.target_encoder is not None and first.target_encoder is not None
    for name, tensor in first.target_encoder.state_dict().items():
        assert th.equal(tensor, saved.target_encoder.state_dict()[name]), name
    resumed, _ = pretrain(data, tmp_path, steps=4, checkpoint_every=2, ef_kwargs=LATENT, **ARGUMENTS)
    assert int(resumed.ef.probe_steps) == 4  # two before the checkpoint, two after


def test_a_target_tau_is_refused_for_pixel_pretraining(tmp_path):
    with pytest.raises(ValueError, match=r"\['target_tau'\] apply to target='latent' only"):
        pretrain(episodes(), tmp_path, steps=1, ef_kwargs={"target_tau": 0.1}, **ARGUMENTS)


@pytest.mark.parametrize("temperature", [float("inf"), float("nan"), 0.0])
def test_a_temperature_that_is_not_finite_and_positive_is_refused_for_latent_pretraining(temperature, tmp_path):
    with pytest.raises(ValueError, match=f"temperature must be a finite positive number, got {temperature}"):
        pretrain(episodes(), tmp_path, steps=1, ef_kwargs={**LATENT, "temperature": temperature}, **ARGUMENTS)


@pytest.mark.parametrize("constant", ["Infinity", "-Infinity", "NaN"])
def test_sb3_ef_pretrain_refuses_a_temperature_that_is_not_finite(constant, capsys):
    with pytest.raises(SystemExit):
        main(["pretrain", "unused", "unused", "--ef-kwargs", f'{{"target": "latent", "temperature": {constant}}}'])
    assert f"argument --ef-kwargs: expected finite numbers, got {constant} in" in capsys.readouterr().err
