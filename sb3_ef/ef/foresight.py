"""Ego-Foresight's modules, pixel (the paper's) and latent, sharing the split and the rollout; the rollout-length
rule (docs/ef.md)."""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th
from torch import nn

from sb3_ef.common.layers import mlp
from sb3_ef.ef.arguments import OPTIONS, STEP_SAMPLINGS, check_ef_kwargs
from sb3_ef.ef.decoder import FrameDecoder
from sb3_ef.ef.latent import (
    DEFAULT_HEAD_HIDDEN_DIM,
    DEFAULT_LOSS_SCALE,
    DEFAULT_PROJECTION_DIM,
    DEFAULT_TEMPERATURE,
    LatentHead,
    info_nce,
)


def draw_rollout_steps(
    future_mask: th.Tensor, horizon: int, step_sampling: str = "batch", generator: th.Generator | None = None
) -> th.Tensor:
    """Draw k in [1, horizon] per sample, a (B,) long tensor: one k per batch or per sample (docs/ef.md, "Choices").

    :param future_mask: (B, H) bool, true where step t+i lies inside the episode; H >= horizon.
    :param horizon: the largest k.
    :param step_sampling: ``"batch"`` or ``"sample"``.
    :param generator: the generator to draw from.
    """
    if step_sampling not in STEP_SAMPLINGS:
        raise ValueError(f"step_sampling must be one of {STEP_SAMPLINGS}, got {step_sampling!r}")
    if future_mask.dim() != 2 or future_mask.shape[1] < horizon:
        raise ValueError(f"Expected future_mask of shape (batch, >= {horizon}), got {tuple(future_mask.shape)}")
    batch = future_mask.shape[0]
    device = generator.device if generator is not None else future_mask.device
    if step_sampling == "batch":
        steps = th.randint(1, horizon + 1, (1,), device=device, generator=generator).expand(batch)
    else:
        weights = future_mask[:, :horizon].to(device=device, dtype=th.float32)
        weights[weights.sum(dim=1) == 0] = 1.0
        steps = th.multinomial(weights, 1, generator=generator).squeeze(1) + 1
    return steps.to(future_mask.device).contiguous()


class RolloutBlock(nn.Module):
    """A recurrent MLP ``h_a(t+1) = FC([h_a(t), a(t)])`` of TD-MPC2-style blocks, with no residual (the authors').

    :param agent_dim: size of the agent features ``h_a``.
    :param action_dim: size of one action.
    :param hidden_dims: widths of the hidden ``NormedLinear`` blocks.
    """

    def __init__(self, agent_dim: int, action_dim: int, hidden_dims: tuple[int, ...] | list[int] = (512, 512)):
        super().__init__()
        self.agent_dim = agent_dim
        self.action_dim = action_dim
        self.net = mlp(agent_dim + action_dim, tuple(hidden_dims), agent_dim)

    def step(self, h_agent: th.Tensor, action: th.Tensor) -> th.Tensor:
        """One step: (B, agent_dim), (B, action_dim) -> (B, agent_dim)."""
        return self.net(th.cat([h_agent, action], dim=-1))

    def forward(self, h_agent: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Roll ``h_agent`` (B, agent_dim) through ``actions`` (B, T, action_dim); returns (B, T, agent_dim)."""
        if h_agent.dim() != 2 or h_agent.shape[1] != self.agent_dim:
            raise ValueError(f"Expected h_agent of shape (batch, {self.agent_dim}), got {tuple(h_agent.shape)}")
        if actions.dim() != 3 or actions.shape[0] != h_agent.shape[0] or actions.shape[2] != self.action_dim:
            raise ValueError(
                f"Expected actions of shape ({h_agent.shape[0]}, steps, {self.action_dim}), got {tuple(actions.shape)}"
            )
        states = []
        for t in range(actions.shape[1]):
            h_agent = self.step(h_agent, actions[:, t])
            states.append(h_agent)
        if not states:
            return h_agent.new_zeros(h_agent.shape[0], 0, self.agent_dim)
        return th.stack(states, dim=1)


class EgoForesight(nn.Module):
    """Predict the frame k steps ahead from h_scene and h_agent rolled out by the actions (docs/ef.md).

    :param feature_dim: size of the encoder features h.
    :param action_dim: size of one action.
    :param frame_shape: (channels, size, size) of the predicted frame (sizes: ``decoder_layers``).
    :param agent_dim: size of h_agent, the first features of h.
    :param horizon: H, the largest rollout length drawn for the loss.
    :param rollout_hidden_dims: hidden widths of the rollout MLP.
    :param decoder_channels: width of the decoder's hidden layers.
    :param skip_channels: channels of the encoder feature map passed as U-Net skip, 0 for none.
    :param step_sampling: ``"batch"`` (one k per batch) or ``"sample"`` (one k per sample).
    :param decode_batch_size: decode only this many samples per batch (``None``: all); changes the method.
    """

    #: What the loss predicts: the frame at t+k (:class:`LatentEgoForesight`: features of the observation at t+k).
    target: ClassVar[str] = "pixel"
    #: Weight of the loss inside EF's, times ``beta`` (1: the paper's squared error as it is).
    loss_scale: float = 1.0

    def __init__(
        self,
        feature_dim: int,
        action_dim: int,
        frame_shape: tuple[int, int, int] = (3, 84, 84),
        agent_dim: int = 32,
        horizon: int = 10,
        rollout_hidden_dims: tuple[int, ...] | list[int] = (512, 512),
        decoder_channels: int = 64,
        skip_channels: int = 0,
        step_sampling: str = "batch",
        decode_batch_size: int | None = None,
    ):
        super().__init__()
        if not 1 <= agent_dim < feature_dim:
            raise ValueError(f"agent_dim must be in [1, feature_dim={feature_dim}), got {agent_dim}")
        if action_dim < 1:
            raise ValueError(f"action_dim must be >= 1, got {action_dim}")
        if horizon < 1:
            raise ValueError(f"horizon must be >= 1, got {horizon}")
        options = {"rollout_hidden_dims": rollout_hidden_dims, "decoder_channels": decoder_channels}
        check_ef_kwargs({**options, "step_sampling": step_sampling, "decode_batch_size": decode_batch_size})
        self.feature_dim = feature_dim
        self.action_dim = action_dim
        self.frame_shape = tuple(frame_shape)
        self.agent_dim = agent_dim
        self.horizon = horizon
        self.skip_channels = skip_channels
        self.step_sampling = step_sampling
        self.decode_batch_size = decode_batch_size
        self.rollout_block = RolloutBlock(agent_dim, action_dim, rollout_hidden_dims)
        self.decoder = FrameDecoder(feature_dim, frame_shape, decoder_channels, skip_channels)

    def __setstate__(self, state: dict[str, Any]) -> None:
        """A module pickled by an earlier version (policy files) kept ``target`` per instance: latent EF's class."""
        if state.pop("target", "pixel") == "latent":
            self.__class__ = LatentEgoForesight
        super().__setstate__(state)

    @property
    def scene_dim(self) -> int:
        """Size of h_scene."""
        return self.feature_dim - self.agent_dim

    def split(self, h: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """(B, feature_dim) -> (h_scene, h_agent); h_agent is the first ``agent_dim`` features."""
        if h.dim() != 2 or h.shape[1] != self.feature_dim:
            raise ValueError(f"Expected features h of shape (batch, {self.feature_dim}), got {tuple(h.shape)}")
        return h[:, self.agent_dim :], h[:, : self.agent_dim]

    def rollout(self, h_agent: th.Tensor, actions: th.Tensor) -> th.Tensor:
        """Roll h_agent (B, agent_dim) forward one action at a time: (B, T, action_dim) -> (B, T, agent_dim)."""
        return self.rollout_block(h_agent, actions)

    def decode(self, h_scene: th.Tensor, h_agent: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        """Decode scene and (predicted) agent features to a (B, C, h, w) frame in [0, 1]."""
        return self.decoder(th.cat([h_agent, h_scene], dim=-1), skip)

    def draw_steps(self, future_mask: th.Tensor, generator: th.Generator | None = None) -> th.Tensor:
        """The rollout length k per sample (:func:`draw_rollout_steps`)."""
        return draw_rollout_steps(future_mask, self.horizon, self.step_sampling, generator)

    def loss(
        self,
        h: th.Tensor,
        future_actions: th.Tensor,
        steps: th.Tensor,
        target: th.Tensor,
        valid: th.Tensor | None = None,
        skip: th.Tensor | None = None,
    ) -> th.Tensor:
        """Squared error of the frame ``steps`` actions ahead, summed over pixels, averaged over valid samples.

        :param h: (B, feature_dim) features of the context.
        :param future_actions: (B, T, action_dim) actions from the context on, T >= max(steps).
        :param steps: (B,) rollout lengths k >= 1, from ``draw_steps``.
        :param target: (B, C, h, w) frame at step k, uint8 or float in [0, 1], shifted with the context.
        :param valid: optional (B,) bool or float weights.
        :param skip: encoder feature map of the context when ``skip_channels > 0``.
        """
        batch = h.shape[0]
        h_scene, h_agent = self.split(h)
        max_step = self._checked_window(batch, future_actions, steps, valid)
        target = self._target_to_float(target, batch)
        if self.decode_batch_size is not None and batch > self.decode_batch_size:
            batch = self.decode_batch_size
            h_scene, h_agent, future_actions, steps, target = (
                x[:batch] for x in (h_scene, h_agent, future_actions, steps, target)
            )
            valid = None if valid is None else valid[:batch]
            skip = None if skip is None else skip[:batch]
        predicted_agent = self._agent_at(h_agent, future_actions, steps, max_step)
        prediction = self.decode(h_scene, predicted_agent, skip)
        per_sample = (prediction - target).pow(2).flatten(1).sum(dim=1)
        return _weighted_mean(per_sample, valid)

    def _checked_window(self, batch: int, future_actions: th.Tensor, steps: th.Tensor, valid: th.Tensor | None) -> int:
        """Check the shapes of a loss's window; return the longest rollout it needs (the window under compile)."""
        if steps.shape != (batch,) or steps.dtype not in (th.int32, th.int64):
            raise ValueError(f"Expected integer steps of shape ({batch},), got {tuple(steps.shape)} {steps.dtype}")
        if future_actions.dim() != 3 or future_actions.shape[0] != batch:
            raise ValueError(
                f"Expected future_actions of shape ({batch}, steps, {self.action_dim}), "
                f"got {tuple(future_actions.shape)}"
            )
        if th.compiler.is_compiling():
            # Static shapes, no device sync: roll out the whole window.
            max_step = future_actions.shape[1]
        else:
            min_step, max_step = th.stack(th.aminmax(steps)).tolist()  # one device sync for both bounds
            if min_step < 1 or max_step > future_actions.shape[1]:
                raise ValueError(f"steps must lie in [1, {future_actions.shape[1]}], got [{min_step}, {max_step}]")
        if valid is not None and valid.shape != (batch,):
            raise ValueError(f"Expected valid of shape ({batch},), got {tuple(valid.shape)}")
        return max_step

    def _agent_at(self, h_agent: th.Tensor, future_actions: th.Tensor, steps: th.Tensor, max_step: int) -> th.Tensor:
        """h_a rolled out, each sample's state at its own k: (B, agent_dim)."""
        agent_states = self.rollout(h_agent, future_actions[:, :max_step])
        return agent_states[th.arange(h_agent.shape[0], device=h_agent.device), steps.long() - 1]

    def predict(self, h: th.Tensor, actions: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        """Open-loop frames for every step of ``actions`` (B, T, action_dim): (B, T, C, h, w); T may exceed H."""
        h_scene, h_agent = self.split(h)
        batch, steps = actions.shape[:2]
        agent_states = self.rollout(h_agent, actions).flatten(0, 1)
        scenes = h_scene.repeat_interleave(steps, dim=0)
        skips = None if skip is None else skip.repeat_interleave(steps, dim=0)
        frames = self.decode(scenes, agent_states, skips)
        return frames.unflatten(0, (batch, steps))

    def _target_to_float(self, target: th.Tensor, batch: int) -> th.Tensor:
        if tuple(target.shape) != (batch, *self.frame_shape):
            raise ValueError(
                f"Expected target of shape ({batch}, {', '.join(map(str, self.frame_shape))}), "
                f"got {tuple(target.shape)}"
            )
        if target.dtype == th.uint8:
            return target.float() / 255.0
        if not target.is_floating_point():
            raise ValueError(f"Expected a uint8 or float target frame, got {target.dtype}")
        low, high = th.stack(th.aminmax(target)).tolist()
        if low < 0.0 or high > 1.0:
            raise ValueError(f"A float target frame must lie in [0, 1], got values in [{low}, {high}]")
        return target


class LatentEgoForesight(EgoForesight):
    """Ego-Foresight in feature space: h_s and the rolled-out h_a predict the target encoder's projection of the
    observation at t+k (InfoNCE); the frame decoder is a probe, trained apart on detached features (docs/ef.md,
    "Ego-Foresight in feature space"). Arguments as :class:`EgoForesight`'s, and:

    :param projection_dim: size of the projected vectors the loss compares.
    :param head_hidden_dim: width of the projection and prediction MLPs.
    :param temperature: the InfoNCE's temperature.
    :param loss_scale: weight of the InfoNCE, times ``beta``.
    """

    target: ClassVar[str] = "latent"
    probe_steps: th.Tensor

    def __init__(
        self,
        *args: Any,
        projection_dim: int = DEFAULT_PROJECTION_DIM,
        head_hidden_dim: int = DEFAULT_HEAD_HIDDEN_DIM,
        temperature: float = DEFAULT_TEMPERATURE,
        loss_scale: float = DEFAULT_LOSS_SCALE,
        **kwargs: Any,
    ):
        latent: dict[str, object] = {"projection_dim": projection_dim, "head_hidden_dim": head_hidden_dim}
        latent.update(temperature=temperature, loss_scale=loss_scale, decode_batch_size=kwargs.get("decode_batch_size"))
        check_ef_kwargs({"target": "latent", **latent})
        super().__init__(*args, **kwargs)
        self.loss_scale = float(loss_scale)
        self.head = LatentHead(self.feature_dim, projection_dim, head_hidden_dim, temperature)
        # Probe decoder updates, counted by whoever fits it: 0 means untrained.
        self.register_buffer("probe_steps", th.zeros((), dtype=th.long))

    def decode(self, h_scene: th.Tensor, h_agent: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        """Decode to a frame through the probe decoder, once it is trained."""
        if int(self.probe_steps) == 0:
            raise ValueError(
                "This Ego-Foresight predicts features (target='latent'): it decodes frames through a probe decoder, "
                "which is not trained yet; fit it first with sb3_ef.ef.probe.fit_probe(model)"
            )
        return super().decode(h_scene, h_agent, skip)

    def loss(
        self,
        h: th.Tensor,
        future_actions: th.Tensor,
        steps: th.Tensor,
        target: th.Tensor,
        valid: th.Tensor | None = None,
        candidates_valid: th.Tensor | None = None,
    ) -> th.Tensor:
        """The InfoNCE of the head's prediction against target projections; arguments as :class:`EgoForesight`'s.

        :param target: (N >= B, projection_dim) target projections: row i < B sample i's at t+k, all rows candidates.
        :param candidates_valid: optional (N,) bool: the candidates inside their episode.
        """
        batch = h.shape[0]
        h_scene, h_agent = self.split(h)
        max_step = self._checked_window(batch, future_actions, steps, valid)
        if target.dim() != 2 or target.shape[0] < batch or target.shape[1] != self.head.projection_dim:
            raise ValueError(
                f"Expected target features of shape (>= {batch}, {self.head.projection_dim}), got {tuple(target.shape)}"
            )
        predicted_agent = self._agent_at(h_agent, future_actions, steps, max_step)
        prediction = self.head(th.cat([predicted_agent, h_scene], dim=-1))
        per_sample = info_nce(prediction, target.detach(), self.head.temperature, candidates_valid)
        return _weighted_mean(per_sample, valid)

    def probe_loss(
        self,
        h: th.Tensor,
        future_actions: th.Tensor,
        steps: th.Tensor,
        target: th.Tensor,
        valid: th.Tensor | None = None,
        skip: th.Tensor | None = None,
    ) -> th.Tensor:
        """Latent EF's probe loss: :meth:`loss`'s error, only the decoder learning from it."""
        batch = h.shape[0]
        with th.no_grad():
            h_scene, h_agent = self.split(h)
            max_step = self._checked_window(batch, future_actions, steps, valid)
            predicted_agent = self._agent_at(h_agent, future_actions, steps, max_step)
        target = self._target_to_float(target, batch)
        features = th.cat([predicted_agent, h_scene], dim=-1)
        prediction = self.decoder(features, None if skip is None else skip.detach())
        return _weighted_mean((prediction - target).pow(2).flatten(1).sum(dim=1), valid)


def ego_foresight(*args: Any, target: str = "pixel", **options: Any) -> EgoForesight:
    """The Ego-Foresight module ``target`` names (``ef_kwargs["target"]``), an option of the other target refused;
    other arguments as :class:`EgoForesight`'s (and :class:`LatentEgoForesight`'s)."""
    check_ef_kwargs({"target": target, **{name: value for name, value in options.items() if name in OPTIONS}})
    if target == "pixel":
        return EgoForesight(*args, **options)
    return LatentEgoForesight(*args, **{name: value for name, value in options.items() if value is not None})


def _weighted_mean(per_sample: th.Tensor, valid: th.Tensor | None) -> th.Tensor:
    """Mean of per-sample losses weighted by ``valid``; 0 when no sample is valid."""
    if valid is None:
        return per_sample.mean()
    weights = valid.to(per_sample.dtype)
    return (per_sample * weights).sum() / weights.sum().clamp(min=1.0)
