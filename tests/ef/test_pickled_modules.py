"""EF modules pickled whole by sb3-ef 0.2.0 (``policy.save`` keeps the auxiliary module so) unpickle into this
version's classes: ``beta`` a float attribute, one module class for both targets, the target's input scaling."""

from __future__ import annotations

import pickle

import torch as th
from torch import nn

from sb3_ef.ef import EgoForesight, ForesightLoss, LatentEgoForesight, LatentForesightLoss, foresight_loss
from sb3_ef.ef.latent import MomentumTarget

FEATURES, ACTIONS, AGENT, H = 24, 2, 6, 3
LATENT = {"target": "latent", "rollout_hidden_dims": (16,), "decoder_channels": 8, "projection_dim": 8}


def as_saved_by_0_2_0(loss: ForesightLoss) -> bytes:
    """``loss`` pickled with the attributes 0.2.0's classes had."""
    state = loss.state_dict()
    beta = float(state.pop("beta"))
    del loss._buffers["beta"]
    loss.__dict__["beta"] = beta
    loss.__class__ = ForesightLoss
    loss.ef.__class__ = EgoForesight
    loss.ef.__dict__["target"] = "latent" if "head" in loss.ef._modules else "pixel"
    target = loss._modules.get("target_encoder")
    if target is None:
        loss.__dict__["target_encoder"] = None  # 0.2.0's pixel EF
    else:
        assert isinstance(target, MomentumTarget)
        del target.__dict__["encode"]
        target.__dict__.update(divisor=255.0, offset=0.5)
    return pickle.dumps(loss)


def test_a_pixel_loss_of_0_2_0_unpickles_with_beta_as_its_buffer():
    saved = foresight_loss(FEATURES, ACTIONS, (3, 16, 16), AGENT, H, beta=0.5, ef_kwargs={"decoder_channels": 8})
    loaded = pickle.loads(as_saved_by_0_2_0(saved))
    assert type(loaded) is ForesightLoss and type(loaded.ef) is EgoForesight and loaded.ef.target == "pixel"
    assert isinstance(loaded.beta, th.Tensor) and float(loaded.beta) == 0.5 and "beta" in loaded.state_dict()


def test_a_latent_loss_of_0_2_0_unpickles_into_the_latent_classes_feeding_its_target_as_before():
    encoder = nn.Sequential(nn.Flatten(), nn.Linear(9 * 16 * 16, FEATURES))
    loss = foresight_loss(FEATURES, ACTIONS, (3, 16, 16), AGENT, H, 0.5, LATENT, encoder=encoder)
    observations = th.randint(0, 256, (4, 9, 16, 16), dtype=th.uint8)
    loaded = pickle.loads(as_saved_by_0_2_0(loss))
    assert type(loaded) is LatentForesightLoss and type(loaded.ef) is LatentEgoForesight
    expected = loaded.target_encoder.projection(encoder(observations.float() / 255.0 - 0.5))
    th.testing.assert_close(loaded.target_encoder(observations), expected)
