"""``check_ef_kwargs``: every option of Ego-Foresight known, a bad key or value named with what is expected."""

from __future__ import annotations

import inspect
import re

import pytest
from torch import nn

from sb3_ef.ef import EgoForesight, LatentEgoForesight, foresight_loss
from sb3_ef.ef.arguments import OPTIONS, SET_BY_CALLER, check_ef_kwargs


def test_every_option_of_ego_foresight_is_known():
    parameters = {
        name
        for module in (EgoForesight, LatentEgoForesight)
        for name in inspect.signature(module.__init__).parameters
        if name not in ("self", "args", "kwargs")
    }
    assert set(OPTIONS) | set(SET_BY_CALLER) == parameters | {"target", "target_tau"}  # LatentForesightLoss's tau


@pytest.mark.parametrize(
    "ef_kwargs",
    [
        {},
        {"rollout_hidden_dims": [8], "decoder_channels": 4, "step_sampling": "sample", "decode_batch_size": 2},
        {"target": "latent", "projection_dim": 8, "head_hidden_dim": 8, "temperature": 0.5, "loss_scale": 0},
        {"target": "latent", "target_tau": 1, "decode_batch_size": None},
    ],
)
def test_options_that_pass_build_an_ego_foresight(ef_kwargs):
    check_ef_kwargs(ef_kwargs)
    loss = foresight_loss(16, 2, (3, 8, 8), 4, 3, ef_kwargs=dict(ef_kwargs), encoder=nn.Linear(8, 16))
    assert loss.ef.target == ef_kwargs.get("target", "pixel")


@pytest.mark.parametrize(
    ("ef_kwargs", "message"),
    [
        ({"decoder_chanels": 32}, "unknown option decoder_chanels=32 (did you mean 'decoder_channels'"),
        ({"target": "latent", "loss_scale": -1}, "ef_kwargs loss_scale must be a finite number >= 0, got -1"),
        ({"target": "latent", "loss_scale": float("nan")}, "loss_scale must be a finite number >= 0, got nan"),
        ({"target": "latent", "loss_scale": "3"}, "ef_kwargs loss_scale must be a finite number >= 0, got str '3'"),
        ({"target": "latent", "loss_scale": True}, "ef_kwargs loss_scale must be a finite number >= 0, got bool True"),
        ({"target": "latent", "temperature": 0}, "ef_kwargs temperature must be a finite positive number, got 0"),
        ({"target": "latent", "target_tau": 2}, "ef_kwargs target_tau must be a number in (0, 1], got 2"),
        ({"target": "latnt"}, "ef_kwargs target must be one of ('pixel', 'latent'), got str 'latnt'"),
        ({"step_sampling": "all"}, "ef_kwargs step_sampling must be one of ('batch', 'sample'), got str 'all'"),
        ({"decoder_channels": 0}, "ef_kwargs decoder_channels must be a positive integer, got 0"),
        ({"rollout_hidden_dims": 8}, "rollout_hidden_dims must be a list of positive integers (hidden widths), got 8"),
        ({"loss_scale": 1}, "ef_kwargs ['loss_scale'] apply to target='latent' only, got target='pixel' (the default)"),
        (
            {"target": "latent", "decode_batch_size": 8},
            "ef_kwargs ['decode_batch_size'] apply to target='pixel' only, got target='latent'",
        ),
        ({"horizon": 5}, "ef_kwargs holds horizon=5, which is set by the algorithm's ef_horizon"),
        ({"agent_dim": 8}, "holds agent_dim=8, which is set by agent_dim (beside ef_kwargs: in policy_kwargs"),
        ({"skip_channels": 8}, "ef_kwargs holds skip_channels=8, which is set by the encoder"),
        ("target='latent'", "must be a mapping of Ego-Foresight's options, e.g. dict(target='latent'), got str"),
    ],
)
def test_a_bad_option_is_named_with_what_is_expected(ef_kwargs, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        check_ef_kwargs(ef_kwargs)
