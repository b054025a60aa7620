"""Ego-Foresight as a host's auxiliary loss: pixel EF (the paper's) and latent EF, two classes sharing the split of
the features and the rollout of h_a (:class:`~sb3_ef.ef.foresight.EgoForesight`); :func:`foresight_loss` picks one
from ``ef_kwargs["target"]``."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any, NamedTuple

import torch as th
from torch import nn

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.ef.arguments import check_ef_kwargs
from sb3_ef.ef.foresight import EgoForesight, LatentEgoForesight, ego_foresight
from sb3_ef.ef.latent import DEFAULT_TARGET_TAU, LatentTargets, MomentumTarget, feed_encoder, latent_targets

#: ``encode(encoder, uint8 observations) -> features``: how a host feeds its encoder.
Encode = Callable[[nn.Module, th.Tensor], th.Tensor]


class ForesightTargets(NamedTuple):
    """What pixel EF's loss compares against for one replay batch."""

    steps: th.Tensor  # (B,) rollout lengths k
    target: th.Tensor  # (B, 3, h, w) uint8 frame t+k, shifted together with the observation at t
    valid: th.Tensor  # (B,) bool: step t+k lies inside the episode
    actions: th.Tensor  # (B, H, action_dim) actions t .. t+H-1


class ForesightLoss(AuxiliaryLoss):
    """Pixel Ego-Foresight (the paper's): ``beta * ||D(h_s, FC^k(h_a, a)) - x_{t+k}||^2`` (docs/ef.md).

    :param feature_dim: size of the host encoder's features h.
    :param action_dim: size of one action.
    :param frame_shape: (3, h, w) of one frame.
    :param agent_dim: size of h_agent, the first features of h (scene features must remain).
    :param horizon: H, the largest rollout length k.
    :param beta: weight of the loss, kept as a buffer of this module (``model.beta`` reads and sets it).
    :param ef_kwargs: extra arguments of :class:`EgoForesight`.
    :param channels_last: keep the decoder's conv weights channels-last (same maths, faster convolutions).
    """

    beta: th.Tensor
    ef: EgoForesight

    def __init__(
        self,
        feature_dim: int,
        action_dim: int,
        frame_shape: tuple[int, int, int],
        agent_dim: int,
        horizon: int,
        beta: float = 1.0,
        ef_kwargs: dict[str, Any] | None = None,
        channels_last: bool = False,
    ):
        super().__init__()
        self.register_coefficient("beta", beta)
        self.ef = ego_foresight(
            feature_dim, action_dim, frame_shape=frame_shape, agent_dim=agent_dim, horizon=horizon, **(ef_kwargs or {})
        )
        if channels_last:
            self.ef.to(memory_format=th.channels_last)  # type: ignore[call-overload]

    def _draw(self, batch: SequenceReplayBufferSamples, generator: th.Generator | None) -> tuple[th.Tensor, th.Tensor]:
        """The rollout length k of each sample (from ``generator``) and whether step t+k lies inside the episode."""
        steps = self.ef.draw_steps(batch.future_mask, generator=generator)
        rows = th.arange(steps.shape[0], device=steps.device)
        return steps, batch.future_mask[rows, steps - 1]

    def prepare(
        self, batch: SequenceReplayBufferSamples, pad: int, generator: th.Generator | None = None
    ) -> tuple[th.Tensor, ForesightTargets]:
        """Draw k; shift the observations at t and the frame t+k together (one shift per sample)."""
        steps, valid = self._draw(batch, generator)
        rows = th.arange(steps.shape[0], device=steps.device)
        observations, target = random_shift(batch.observations, batch.future_frames[rows, steps - 1], pad=pad)
        return observations, ForesightTargets(steps, target, valid, batch.future_actions)

    def forward(self, features: th.Tensor, targets: ForesightTargets) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """``beta`` times EF's squared error (summed over pixels, averaged over valid samples); logs ``ef_loss``."""
        loss = self.ef.loss(features, targets.actions, targets.steps, targets.target, targets.valid)
        return self.weighted(self.beta * self.ef.loss_scale, loss), {"ef_loss": loss.detach()}

    def __setstate__(self, state: dict[str, Any]) -> None:
        """A loss pickled by an earlier version (policy files): ``beta`` a float, latent EF in this class."""
        super().__setstate__(state)
        if "target_encoder" in state["_modules"]:
            self.__class__ = LatentForesightLoss
        if "beta" in state:
            self.register_coefficient("beta", self.__dict__.pop("beta"))


class LatentForesightLoss(ForesightLoss):
    """Latent Ego-Foresight: the rolled-out h_a with h_s predict a momentum target's projection of the observation at
    t+k (InfoNCE against the batch's other targets and each sample's own other step); its frame decoder is a probe
    (docs/ef.md, "Ego-Foresight in feature space"). Arguments as :class:`ForesightLoss`'s, and:

    :param encoder: the host's online encoder (not stored: the target is a momentum copy of it).
    :param encode: how the host computes features from ``encoder`` and uint8 observations; the copy is run so.
    """

    ef: LatentEgoForesight

    def __init__(self, *args: Any, encoder: nn.Module, encode: Encode = feed_encoder, **kwargs: Any):
        bound = inspect.signature(ForesightLoss).bind(*args, **kwargs)
        options = {"target": "latent", **(bound.arguments.get("ef_kwargs") or {})}
        target_tau = options.pop("target_tau", DEFAULT_TARGET_TAU)
        super().__init__(**{**bound.arguments, "ef_kwargs": options})
        self.target_encoder = MomentumTarget(encoder, self.ef.head.projection, target_tau, encode)

    def prepare(  # type: ignore[override]
        self, batch: SequenceReplayBufferSamples, pad: int, generator: th.Generator | None = None
    ) -> tuple[th.Tensor, LatentTargets]:
        """Draw k and another step k' per sample; each target shifted on its own, none sharing the anchor's shift."""
        steps, valid = self._draw(batch, generator)
        return latent_targets(batch, steps, valid, self.ef.horizon, pad, generator)

    def forward(self, features: th.Tensor, targets: LatentTargets) -> tuple[th.Tensor, dict[str, th.Tensor]]:  # type: ignore[override]
        """``beta * loss_scale`` times the InfoNCE of the prediction against the target projections."""
        future = targets.observations
        if targets.negatives is not None:
            future = th.cat([future, targets.negatives])
        target = self.target_encoder(future)
        loss = self.ef.loss(
            features, targets.actions, targets.steps, target, targets.valid, targets.candidates_valid()
        )
        return self.weighted(self.beta * self.ef.loss_scale, loss), {"ef_loss": loss.detach()}

    def after_update(self, encoder: nn.Module) -> None:
        """The target encoder and projection follow the online ones."""
        self.target_encoder.update(encoder, self.ef.head.projection)


def foresight_loss(
    feature_dim: int,
    action_dim: int,
    frame_shape: tuple[int, int, int],
    agent_dim: int,
    horizon: int,
    beta: float = 1.0,
    ef_kwargs: dict[str, Any] | None = None,
    channels_last: bool = False,
    encoder: nn.Module | None = None,
    encode: Encode = feed_encoder,
) -> ForesightLoss:
    """The EF loss ``ef_kwargs["target"]`` names (``"pixel"``, the default, or ``"latent"``) on ``encoder``."""
    options = dict(ef_kwargs or {})
    check_ef_kwargs(options)
    if options.get("target", "pixel") != "latent":
        return ForesightLoss(feature_dim, action_dim, frame_shape, agent_dim, horizon, beta, options, channels_last)
    if encoder is None:
        raise ValueError("target='latent' predicts the features of the host's encoder: pass encoder=")
    return LatentForesightLoss(
        feature_dim, action_dim, frame_shape, agent_dim, horizon, beta, options, channels_last,
        encoder=encoder, encode=encode,
    )  # fmt: skip
