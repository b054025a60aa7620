"""Ego-Foresight in feature space (``ef_kwargs=dict(target="latent")``): the pieces that replace the frame decoder,
a momentum target encoder, a projection and prediction head, and an InfoNCE (docs/ef.md, "Ego-Foresight in feature
space")."""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import TYPE_CHECKING, NamedTuple

import torch as th
from torch import nn
from torch.nn import functional as F

from sb3_ef.auxiliary.momentum import momentum_copy, momentum_update
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.layers import mlp
from sb3_ef.common.precision import float32

if TYPE_CHECKING:
    from sb3_ef.common.buffers import SequenceReplayBufferSamples

#: Momentum of the target encoder, moved after every update.
DEFAULT_TARGET_TAU = 0.01
DEFAULT_PROJECTION_DIM = 256
DEFAULT_HEAD_HIDDEN_DIM = 512
DEFAULT_TEMPERATURE = 0.1
#: Weight of the InfoNCE inside EF's loss, so that latent EF pulls about as hard as pixel EF (docs/ef.md).
DEFAULT_LOSS_SCALE = 3.0


class LatentTargets(NamedTuple):
    """What latent EF's loss compares against for one replay batch."""

    steps: th.Tensor  # (B,) rollout lengths k
    observations: th.Tensor  # (B, 3 * frame_stack, h, w) uint8 stacked observation at t+k, its own random shift
    valid: th.Tensor  # (B,) bool: step t+k lies inside the episode
    actions: th.Tensor  # (B, H, action_dim) actions t .. t+H-1
    negatives: th.Tensor | None  # (B, 3 * frame_stack, h, w) each sample's observation at t+k', k' != k; None if H = 1
    negatives_valid: th.Tensor | None  # (B,) bool: step t+k' lies inside the episode; None if H = 1

    def candidates_valid(self) -> th.Tensor:
        """(N,) bool: which candidates ``[observations, negatives]`` lie inside their episode."""
        return self.valid if self.negatives_valid is None else th.cat([self.valid, self.negatives_valid])


def draw_other_steps(
    future_mask: th.Tensor, steps: th.Tensor, horizon: int, generator: th.Generator | None = None
) -> th.Tensor | None:
    """Per sample a step k' != k, uniform among its valid steps (all others if none): (B,) long, ``None`` if H = 1."""
    if horizon == 1:
        return None
    device = generator.device if generator is not None else future_mask.device
    rows = th.arange(steps.shape[0], device=device)
    own = steps.to(device) - 1
    weights = future_mask[:, :horizon].to(device=device, dtype=th.float32)
    weights[rows, own] = 0.0
    lonely = weights.sum(dim=1) == 0
    weights[lonely] = 1.0
    weights[rows, own] = 0.0
    others = th.multinomial(weights, 1, generator=generator).squeeze(1) + 1
    return others.to(future_mask.device)


def stacked_observations_at(observations: th.Tensor, future_frames: th.Tensor, steps: th.Tensor) -> th.Tensor:
    """The stacked observation at t+k of each sample, rebuilt from the replay window (oldest frame first).

    :param observations: (B, C * frame_stack, h, w) stacked observations at t.
    :param future_frames: (B, H, C, h, w) the newest frame of the observations t+1 .. t+H (C: 3 for RGB, 1 grey).
    :param steps: (B,) k in [1, H] per sample.
    """
    batch, channels, height, width = observations.shape
    frame_channels = future_frames.shape[2] if future_frames.dim() == 5 else 0
    if (
        not frame_channels
        or channels % frame_channels
        or future_frames.shape[0] != batch
        or tuple(future_frames.shape[3:]) != (height, width)
    ):
        raise ValueError(
            f"Expected observations (batch, C * frame_stack, h, w) and future_frames (batch, H, C, h, w), got "
            f"{tuple(observations.shape)} and {tuple(future_frames.shape)}"
        )
    frame_stack, horizon = channels // frame_channels, future_frames.shape[1]
    context = observations.unflatten(1, (frame_stack, frame_channels))
    rows = th.arange(batch, device=observations.device)
    stacked = []
    for slot in range(frame_stack):  # slot j of the observation at t+k is frame t+k-frame_stack+1+j
        index = steps + slot  # in the context's frames for index < frame_stack, else future frame index - frame_stack
        from_context = context[rows, index.clamp(max=frame_stack - 1)]
        from_future = future_frames[rows, (index - frame_stack).clamp(0, horizon - 1)]
        stacked.append(th.where((index < frame_stack)[:, None, None, None], from_context, from_future))
    return th.stack(stacked, dim=1).flatten(1, 2)


def info_nce(
    prediction: th.Tensor, candidates: th.Tensor, temperature: float, candidates_valid: th.Tensor | None = None
) -> th.Tensor:
    """Per-sample (B,) InfoNCE: cross-entropy of picking candidate i for prediction i, on cosine similarities.

    :param prediction: (B, P) predictions.
    :param candidates: (N >= B, P): row i < B is prediction i's positive, every row a negative of the others.
    :param temperature: divides the similarities.
    :param candidates_valid: optional (N,) bool: invalid candidates are left out of all softmaxes but their own.
    """
    with float32(prediction.device.type):  # the softmax's input in float32 (a small matmul), as CURL's
        logits = F.normalize(prediction.float(), dim=-1) @ F.normalize(candidates.float(), dim=-1).T / temperature
    rows = th.arange(prediction.shape[0], device=prediction.device)
    if candidates_valid is not None:
        left_out = (~candidates_valid.to(device=logits.device, dtype=th.bool))[None, :].expand_as(logits).clone()
        left_out[rows, rows] = False
        logits = logits.masked_fill(left_out, float("-inf"))
    return F.cross_entropy(logits, rows, reduction="none")


class LatentHead(nn.Module):
    """Latent EF's online side: a projection of the features and a prediction head, MLPs of one hidden block.

    :param feature_dim: size of the features (``h`` of the host's encoder).
    :param projection_dim: size of the projected vectors the loss compares.
    :param hidden_dim: width of the hidden block of both MLPs.
    :param temperature: the InfoNCE's temperature (:func:`info_nce`).

    Its sizes and temperature are checked by :class:`~sb3_ef.ef.foresight.LatentEgoForesight`, which builds it.
    """

    def __init__(
        self, feature_dim: int, projection_dim: int, hidden_dim: int, temperature: float = DEFAULT_TEMPERATURE
    ):
        super().__init__()
        self.projection_dim = projection_dim
        self.temperature = float(temperature)
        self.projection = mlp(feature_dim, (hidden_dim,), projection_dim)
        self.prediction = mlp(projection_dim, (hidden_dim,), projection_dim)

    def forward(self, features: th.Tensor) -> th.Tensor:
        """(B, feature_dim) -> (B, projection_dim): the prediction of the target's projection."""
        return self.prediction(self.projection(features))


def feed_encoder(encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    """The default ``encode``: the encoder takes the uint8 stacked observations as they are."""
    return encoder(observations)


def _scaled_input(divisor: float, offset: float, encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    return encoder(observations.float() / divisor - offset)


class MomentumTarget(nn.Module):
    """Latent EF's target: momentum copies (buffers, always in eval mode) of the host's encoder and the projection.

    :param encoder: the host's online encoder, the module the host passes to ``after_update``.
    :param projection: the online projection (:attr:`LatentHead.projection`).
    :param tau: the momentum update's step, in (0, 1].
    :param encode: how the host computes features from its encoder and uint8 observations,
        ``encode(encoder, observations)`` (a module-level function, so that the loss pickles); the copy is run so.
    """

    def __init__(
        self,
        encoder: nn.Module,
        projection: nn.Module,
        tau: float = DEFAULT_TARGET_TAU,
        encode: Callable[[nn.Module, th.Tensor], th.Tensor] = feed_encoder,
    ):
        super().__init__()
        if isinstance(tau, bool) or not isinstance(tau, (int, float)) or not 0.0 < tau <= 1.0:
            raise ValueError(f"target_tau must be a number in (0, 1], got {tau!r}")
        if not isinstance(encoder, nn.Module):
            raise ValueError(f"target='latent' needs the host's encoder (an nn.Module), got {encoder!r}")
        if not callable(encode):
            raise ValueError(f"encode must be a callable encode(encoder, observations), got {encode!r}")
        self.tau = float(tau)
        self.encode = encode
        self.encoder = momentum_copy(encoder)
        self.projection = momentum_copy(projection)

    def __setstate__(self, state: dict[str, object]) -> None:
        """A target pickled by an earlier version (policy files) fed its encoder ``obs / divisor - offset``."""
        if "encode" not in state:
            state["encode"] = partial(_scaled_input, float(state.pop("divisor")), float(state.pop("offset")))  # type: ignore[arg-type]
        super().__setstate__(state)

    def train(self, mode: bool = True) -> MomentumTarget:
        """The copies stay in eval mode."""
        return super().train(False)

    @th.no_grad()
    def features(self, observations: th.Tensor) -> th.Tensor:
        """The target encoder's features (its first output if several) of uint8 stacked observations."""
        output = self.encode(self.encoder, observations)
        return output[0] if isinstance(output, tuple) else output

    @th.no_grad()
    def forward(self, observations: th.Tensor) -> th.Tensor:
        """The target projections ``(B, projection_dim)`` of uint8 stacked observations."""
        return self.projection(self.features(observations))

    def copy_from(self, encoder: nn.Module, projection: nn.Module) -> None:
        """Set the copies to the online ``encoder`` and ``projection`` (after their weights were loaded)."""
        self._move(encoder, projection, 1.0)

    def update(self, encoder: nn.Module, projection: nn.Module) -> None:
        """Move the copies towards the online ``encoder`` and ``projection``."""
        self._move(encoder, projection, self.tau)

    def _move(self, encoder: nn.Module, projection: nn.Module, tau: float) -> None:
        momentum_update(encoder, self.encoder, tau, "encoder")
        momentum_update(projection, self.projection, tau, "projection")


def latent_targets(
    batch: SequenceReplayBufferSamples,
    steps: th.Tensor,
    valid: th.Tensor,
    horizon: int,
    pad: int,
    generator: th.Generator | None = None,
) -> tuple[th.Tensor, LatentTargets]:
    """Latent EF's ``ForesightLoss.prepare``: each target shifted on its own, none sharing the anchor's shift."""
    future = [stacked_observations_at(batch.observations, batch.future_frames, steps)]
    others = draw_other_steps(batch.future_mask, steps, horizon, generator)
    negatives_valid = None
    if others is not None:
        future.append(stacked_observations_at(batch.observations, batch.future_frames, others))
        rows = th.arange(steps.shape[0], device=steps.device)
        negatives_valid = batch.future_mask[rows, others - 1]
    (observations,) = random_shift(batch.observations, pad=pad)
    (shifted,) = random_shift(th.cat(future), pad=pad, generator=generator)
    batch_size = steps.shape[0]
    negatives = shifted[batch_size:] if others is not None else None
    return observations, LatentTargets(
        steps, shifted[:batch_size], valid, batch.future_actions, negatives, negatives_valid
    )
