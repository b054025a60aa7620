"""CURL's contrastive loss (Laskin et al., ICML 2020): InfoNCE between two random crops of each observation.

Each observation is cropped twice at random. The query crop goes through the online encoder (the host's, shared
with its critic), the key crop through a momentum copy of it. With a learned bilinear matrix W the logits are
``z_q W z_k^T`` (batch x batch), the key of the same observation is the positive (the diagonal), the others the
negatives, and the loss is the cross-entropy with labels ``0 .. batch - 1``. After the update the key encoder
moves towards the online one by ``encoder_tau``.
"""

from __future__ import annotations

import copy
from typing import Any

import torch as th
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.utils import polyak_update
from torch import nn
from torch.nn import functional as F

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_crop


class CURLLoss(AuxiliaryLoss):
    """CURL's bilinear InfoNCE on the host encoder's features, with a momentum key encoder.

    :param encoder: the online encoder (the host critic's features extractor, e.g.
        :class:`~sb3_ef.curl.CURLEncoder`): copied into the key encoder, which must take the raw uint8 crops.
        It is not stored here (the host owns it); ``after_update`` receives it again.
    :param crop_size: side of the random crops (84 for the paper's 100x100 renders), at most the frame size.
    :param encoder_tau: the key encoder's momentum update, ``key <- (1 - tau) key + tau online`` (0.05).
    :param key_update_interval: the key encoder moves on every ``key_update_interval``-th ``after_update``
        (CURL's ``critic_target_update_freq``, 2).
    """

    def __init__(
        self, encoder: BaseFeaturesExtractor, crop_size: int, encoder_tau: float = 0.05, key_update_interval: int = 2
    ):
        super().__init__()
        if not isinstance(encoder, BaseFeaturesExtractor):
            raise ValueError(
                f"CURLLoss needs the host's features extractor (an SB3 BaseFeaturesExtractor), got {encoder!r}"
            )
        shape = encoder._observation_space.shape
        if shape is None or len(shape) != 3:
            raise ValueError(f"CURLLoss needs an encoder of (channels, height, width) frames, got shape {shape}")
        _, height, width = shape
        if isinstance(crop_size, bool) or not isinstance(crop_size, int) or not 1 <= crop_size <= min(height, width):
            raise ValueError(
                f"CURL's crop_size must be an int in [1, {min(height, width)}] (at most the {height}x{width} "
                f"frames), got {crop_size!r}"
            )
        if not 0.0 < encoder_tau <= 1.0:
            raise ValueError(f"encoder_tau must be in (0, 1], got {encoder_tau!r}")
        if isinstance(key_update_interval, bool) or not isinstance(key_update_interval, int) or key_update_interval < 1:
            raise ValueError(f"key_update_interval must be a positive int, got {key_update_interval!r}")
        self.crop_size = crop_size
        self.encoder_tau = encoder_tau
        self.key_update_interval = key_update_interval
        self.features_dim = encoder.features_dim
        self.key_encoder = copy.deepcopy(encoder).requires_grad_(False)
        # CURL's initialisation of W: uniform in [0, 1).
        self.W = nn.Parameter(th.rand(self.features_dim, self.features_dim))
        self._updates = 0  # after_update calls, saved with the state dict so a resumed run keeps the phase

    def prepare(self, batch: Any, pad: int, generator: th.Generator | None = None) -> tuple[th.Tensor, th.Tensor]:
        """Two independent random crops of ``batch.observations``: the queries (the host encodes them) and the
        keys (the target). ``pad`` is not used: CURL's augmentation is the crop."""
        observations = batch.observations
        if observations.dim() != 4 or min(observations.shape[-2:]) < self.crop_size:
            raise ValueError(
                f"CURL crops {self.crop_size}x{self.crop_size} windows of (batch, channels, height, width) frames at "
                f"least that large, got observations of shape {tuple(observations.shape)}"
            )
        (queries,) = random_crop(observations, size=self.crop_size, generator=generator)
        (keys,) = random_crop(observations, size=self.crop_size, generator=generator)
        return queries, keys

    def logits(self, queries: th.Tensor, keys: th.Tensor) -> th.Tensor:
        """``z_q W z_k^T`` minus each row's maximum: (batch, batch), the positives on the diagonal."""
        logits = queries @ (self.W @ keys.T)
        return logits - logits.max(dim=1, keepdim=True).values

    def forward(self, features: th.Tensor, targets: th.Tensor) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        if features.dim() != 2 or features.shape[1] != self.features_dim:
            raise ValueError(
                f"CURL expects features of shape (batch, {self.features_dim}), got {tuple(features.shape)}"
            )
        with th.no_grad():
            keys = self.key_encoder(targets)
        logits = self.logits(features, keys)
        loss = F.cross_entropy(logits, th.arange(logits.shape[0], device=logits.device))
        return loss, {"curl_loss": loss.detach()}

    def after_update(self, encoder: nn.Module) -> None:
        """Every ``key_update_interval``-th call: ``key <- (1 - encoder_tau) key + encoder_tau online``."""
        self._updates += 1
        if self._updates % self.key_update_interval == 0:
            polyak_update(encoder.parameters(), self.key_encoder.parameters(), self.encoder_tau)

    def get_extra_state(self) -> dict[str, int]:
        return {"updates": self._updates}

    def set_extra_state(self, state: dict[str, int]) -> None:
        self._updates = int(state["updates"])
