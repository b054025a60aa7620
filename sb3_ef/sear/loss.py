"""SEAR's auxiliary losses: the latent's halves decoded to the frames and their agent masks (docs/sear.md)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, NamedTuple

import torch as th
from torch.nn import functional as F

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.sear.decoder import SEARDecoder

#: Named (reconstruction_coef, mask_coef) pairs: ``"sear"`` is the SEAR authors' setting (sear-rl
#: ``cfgs/agent/sear.yaml``), ``"efrl"`` the Ego-Foresight authors' copy of it (ego-foresight/efrl).
SEAR_COEFFICIENTS: dict[str, tuple[float, float]] = {"sear": (1.0, 0.25), "efrl": (0.01, 0.0025)}

#: SEAR's latent size (``latent_dim`` of its encoder's projection).
SEAR_LATENT_DIM = 4096


class SEARTargets(NamedTuple):
    """The shifted observations and their agent masks, shifted with them."""

    frames: th.Tensor  # (batch, 3 * frame_stack, height, width), uint8
    masks: th.Tensor  # (batch, frame_stack, height, width), 0/1


def resolve_coefficients(coefficients: str | Sequence[float]) -> tuple[float, float]:
    """``(reconstruction_coef, mask_coef)`` of a :data:`SEAR_COEFFICIENTS` preset name or of a pair of numbers."""
    if isinstance(coefficients, str):
        if coefficients not in SEAR_COEFFICIENTS:
            raise ValueError(
                f"Unknown SEAR coefficient preset {coefficients!r}: expected one of {sorted(SEAR_COEFFICIENTS)} "
                "or a pair (reconstruction_coef, mask_coef)"
            )
        return SEAR_COEFFICIENTS[coefficients]
    pair: tuple[Any, ...] = tuple(coefficients) if isinstance(coefficients, Sequence) else ()
    if len(pair) != 2 or not all(isinstance(c, (int, float)) and not isinstance(c, bool) and c >= 0 for c in pair):
        raise ValueError(
            f"SEAR coefficients must be a preset name {sorted(SEAR_COEFFICIENTS)} or a pair of non-negative "
            f"numbers (reconstruction_coef, mask_coef), got {coefficients!r}"
        )
    return float(pair[0]), float(pair[1])


class SEARLoss(AuxiliaryLoss):
    """SEAR's frame decoder and mask decoder on the two halves of the host encoder's features.

    :param features_dim: size of the encoder's features (even: split in halves); SEAR uses 4096.
    :param observation_shape: ``(3 * frame_stack, height, width)`` of the stacked observations.
    :param coefficients: a :data:`SEAR_COEFFICIENTS` name or a pair ``(reconstruction_coef, mask_coef)``.
    """

    reconstruction_coef: th.Tensor
    mask_coef: th.Tensor

    def __init__(
        self,
        features_dim: int,
        observation_shape: Sequence[int],
        coefficients: str | Sequence[float] = "sear",
    ):
        super().__init__()
        if isinstance(features_dim, bool) or not isinstance(features_dim, int) or features_dim < 2 or features_dim % 2:
            raise ValueError(
                f"SEAR splits the encoder's features in halves: features_dim must be an even int >= 2, "
                f"got {features_dim!r}"
            )
        shape = tuple(observation_shape)
        if len(shape) != 3 or shape[0] % FRAME_CHANNELS or shape[0] == 0:
            raise ValueError(
                f"SEAR expects observations of shape (3 * frame_stack, height, width), got {observation_shape!r}"
            )
        reconstruction_coef, mask_coef = resolve_coefficients(coefficients)
        self.register_coefficient("reconstruction_coef", reconstruction_coef)
        self.register_coefficient("mask_coef", mask_coef)
        self.features_dim = features_dim
        self.observation_shape: tuple[int, int, int] = shape
        self.frame_stack = shape[0] // FRAME_CHANNELS
        half = features_dim // 2
        self.frame_decoder = SEARDecoder(half, shape[0], shape[1], shape[2])
        self.mask_decoder = SEARDecoder(half, self.frame_stack, shape[1], shape[2])

    @property
    def mask_shape(self) -> tuple[int, int, int]:
        return (self.frame_stack, *self.observation_shape[1:])

    def prepare(self, batch: Any, pad: int, generator: th.Generator | None = None) -> tuple[th.Tensor, SEARTargets]:
        """The observations and their agent masks shifted alike: the encoder's input and the targets."""
        observations = batch.observations
        masks = getattr(batch, "masks", None)
        if masks is None:
            raise ValueError(
                "SEAR needs the agent mask of every stacked frame (batch.masks): build the env with "
                "make_env(..., agent_masks=True) and the replay buffer with store_masks=True"
            )
        expected = (observations.shape[0], *self.mask_shape)
        if tuple(observations.shape[1:]) != self.observation_shape or tuple(masks.shape) != expected:
            raise ValueError(
                f"SEAR expects observations (batch, {', '.join(map(str, self.observation_shape))}) and masks "
                f"{expected}, got {tuple(observations.shape)} and {tuple(masks.shape)}"
            )
        observations, masks = random_shift(observations, masks, pad=pad, generator=generator)
        return observations, SEARTargets(observations, masks)

    def split(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """The halves of the features: decoded to frames and to agent masks."""
        if features.dim() != 2 or features.shape[1] != self.features_dim:
            raise ValueError(
                f"SEAR expects features of shape (batch, {self.features_dim}), got {tuple(features.shape)}"
            )
        half = self.features_dim // 2
        return features[:, :half], features[:, half:]

    def decode(self, features: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Decoded frames (clamped to [-0.5, 0.5], the scale of ``obs / 255 - 0.5``) and agent-mask probabilities."""
        first, second = self.split(features)
        return self.frame_decoder(first).clamp(-0.5, 0.5), th.sigmoid(self.mask_decoder(second))

    def forward(self, features: th.Tensor, targets: SEARTargets) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        first, second = self.split(features)
        frames = self.frame_decoder(first).clamp(-0.5, 0.5)
        target_frames = targets.frames.float() / 255.0 - 0.5
        reconstruction = (frames - target_frames).square().flatten(1).sum(dim=1).mean()
        # BCE on logits: BCE on sigmoid outputs without its log clamp at -100.
        mask_logits = self.mask_decoder(second)
        mask = F.binary_cross_entropy_with_logits(mask_logits, targets.masks.float(), reduction="none")
        mask = mask.flatten(1).sum(dim=1).mean()
        loss = self.weighted(self.reconstruction_coef, reconstruction) + self.weighted(self.mask_coef, mask)
        return loss, {"reconstruction_loss": reconstruction.detach(), "mask_loss": mask.detach()}
