"""CURL's contrastive loss: bilinear InfoNCE between two random crops of each observation (docs/curl.md)."""

from __future__ import annotations

import copy
from typing import Any, cast

import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn
from torch.nn import functional as F

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.auxiliary.momentum import momentum_update
from sb3_ef.common.precision import float32
from sb3_ef.curl.crop import check_crop_size, random_crops


class CURLLoss(AuxiliaryLoss):
    """CURL's bilinear InfoNCE on the host encoder's features, with a momentum key encoder.

    :param encoder: the host's online encoder of raw uint8 crops (not stored: ``after_update`` receives it again).
    :param crop_size: side of the random crops, at most the frame size.
    :param key_encoder: the host's momentum encoder, which the host saves and moves; ``None``: a copy kept here.
    :param encoder_tau: with no ``key_encoder``: the copy's momentum (the authors' 0.05).
    :param key_update_interval: with no ``key_encoder``: the copy moves every this many ``after_update`` calls.
    """

    updates: th.Tensor

    def __init__(
        self,
        encoder: BaseFeaturesExtractor,
        crop_size: int,
        key_encoder: BaseFeaturesExtractor | None = None,
        encoder_tau: float | None = None,
        key_update_interval: int | None = None,
    ):
        super().__init__()
        for name, module in (("encoder", encoder), ("key_encoder", key_encoder)):
            if module is not None and not isinstance(module, BaseFeaturesExtractor):
                raise ValueError(
                    f"CURLLoss's {name} must be a features extractor (an SB3 BaseFeaturesExtractor), got {module!r}"
                )
        shape = encoder._observation_space.shape
        if shape is None or len(shape) != 3:
            raise ValueError(f"CURLLoss needs an encoder of (channels, height, width) frames, got shape {shape}")
        self.crop_size = check_crop_size(crop_size, shape[1], shape[2], "CURL")
        self.features_dim = encoder.features_dim
        if key_encoder is not None:
            if (encoder_tau, key_update_interval) != (None, None):
                raise ValueError(
                    "CURLLoss: encoder_tau and key_update_interval move its own key encoder; a given key_encoder is "
                    f"moved by its host, got encoder_tau={encoder_tau!r}, key_update_interval={key_update_interval!r}"
                )
            # Not a submodule: the host owns, saves and moves it.
            object.__setattr__(self, "key_encoder", key_encoder)
        else:
            encoder_tau = 0.05 if encoder_tau is None else encoder_tau
            key_update_interval = 2 if key_update_interval is None else key_update_interval
            if isinstance(encoder_tau, bool) or not isinstance(encoder_tau, (int, float)) or not 0 < encoder_tau <= 1:
                raise ValueError(f"encoder_tau must be in (0, 1], got {encoder_tau!r}")
            if (
                isinstance(key_update_interval, bool)
                or not isinstance(key_update_interval, int)
                or key_update_interval < 1
            ):
                raise ValueError(f"key_update_interval must be a positive int, got {key_update_interval!r}")
            self.key_encoder = copy.deepcopy(encoder).requires_grad_(False)
        self.owns_key_encoder = key_encoder is None
        self.encoder_tau = encoder_tau
        self.key_update_interval = key_update_interval
        self.W = nn.Parameter(th.rand(self.features_dim, self.features_dim))
        # In the state dict, so that a resumed run keeps the key encoder's phase.
        self.register_buffer("updates", th.zeros((), dtype=th.long))

    def prepare(self, batch: Any, pad: int, generator: th.Generator | None = None) -> tuple[th.Tensor, th.Tensor]:
        """Two independent random crops of ``batch.observations``: anchors and positives (``pad`` is unused)."""
        observations = batch.observations
        if observations.dim() != 4 or min(observations.shape[-2:]) < self.crop_size:
            raise ValueError(
                f"CURL crops {self.crop_size}x{self.crop_size} windows of (batch, channels, height, width) frames at "
                f"least that large, got observations of shape {tuple(observations.shape)}"
            )
        anchors = random_crops(observations, self.crop_size, generator)
        return anchors, random_crops(observations, self.crop_size, generator)

    def logits(self, anchors: th.Tensor, positives: th.Tensor) -> th.Tensor:
        """``z_a W z_pos^T`` minus each row's maximum: (batch, batch), the positives on the diagonal."""
        with float32(anchors.device.type):  # the softmax's input in float32: bf16 keeps 3 digits of large logits
            logits = anchors.float() @ (self.W @ positives.float().T)
        return logits - logits.max(dim=1, keepdim=True).values

    def forward(self, features: th.Tensor, targets: th.Tensor) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """InfoNCE of the anchors' ``features`` against the key encoder's features of the positives ``targets``."""
        if features.dim() != 2 or features.shape[1] != self.features_dim:
            raise ValueError(
                f"CURL expects features of shape (batch, {self.features_dim}), got {tuple(features.shape)}"
            )
        with th.no_grad():
            positives = self.key_encoder(targets)
        logits = self.logits(features, positives)
        loss = F.cross_entropy(logits, th.arange(logits.shape[0], device=logits.device))
        return loss, {"curl_loss": loss.detach()}

    def after_update(self, encoder: nn.Module) -> None:
        """Count the update and, with a key encoder of its own, move it every ``key_update_interval`` calls."""
        self.updates += 1
        if self.owns_key_encoder and int(self.updates) % cast(int, self.key_update_interval) == 0:
            momentum_update(encoder, self.key_encoder, cast(float, self.encoder_tau), "encoder")
