"""The Ego-Foresight module: agent/scene split, action-conditioned rollout, frame decoding and its loss."""

from __future__ import annotations

import torch as th
from torch import nn

from sb3_ef.ef.decoder import FrameDecoder
from sb3_ef.ef.rollout import RolloutBlock
from sb3_ef.ef.steps import STEP_SAMPLINGS, draw_rollout_steps


class EgoForesight(nn.Module):
    """Self-supervised agent-aware features: predict the frame k steps ahead from h_scene and a rolled-out h_agent.

    The encoder's features ``h`` (B, feature_dim) are split into agent features (the first ``agent_dim``) and
    scene features (the rest). Only the agent features are moved forward, by the actions, so the encoder is pushed
    to put whatever the actions control (the agent's body) into them.

    :param feature_dim: size of the encoder features h.
    :param action_dim: size of one action.
    :param frame_shape: (channels, size, size) of the predicted frame (see ``decoder_layers`` for the sizes).
    :param agent_dim: size of h_agent, the first features of h.
    :param horizon: H, the largest rollout length drawn for the loss.
    :param rollout_hidden_dims: hidden widths of the rollout MLP.
    :param decoder_channels: width of the decoder's hidden layers.
    :param skip_channels: channels of the encoder feature map passed as U-Net skip, 0 for none.
    :param step_sampling: ``"batch"`` (one k per batch) or ``"sample"`` (one k per sample), see ``draw_steps``.
    :param decode_batch_size: decode only the first this-many samples of each batch in :meth:`loss` (a random subset,
        since replay batches are drawn at random); ``None`` decodes all, as the paper does. **Changes the method**:
        fewer reconstructions per update, so a noisier EF gradient at a lower cost (the decoder dominates it).
    """

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
        if step_sampling not in STEP_SAMPLINGS:
            raise ValueError(f"step_sampling must be one of {STEP_SAMPLINGS}, got {step_sampling!r}")
        if decode_batch_size is not None and decode_batch_size < 1:
            raise ValueError(f"decode_batch_size must be None or >= 1, got {decode_batch_size}")
        self.feature_dim = feature_dim
        self.action_dim = action_dim
        self.frame_shape = tuple(frame_shape)
        self.agent_dim = agent_dim
        self.horizon = horizon
        self.skip_channels = skip_channels
        self.step_sampling = step_sampling
        self.decode_batch_size = decode_batch_size
        self.rollout_block = RolloutBlock(agent_dim, action_dim, rollout_hidden_dims)
        self.decoder = FrameDecoder(feature_dim, self.frame_shape, decoder_channels, skip_channels)

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
        """The rollout length k in [1, horizon] per sample, (B,) long; the rule is in ``draw_rollout_steps``."""
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

        Only max(steps) rollout steps are computed (all of ``future_actions`` under ``torch.compile``, whose checks
        of ``steps`` are skipped); each sample's prediction is gathered at its own k.

        :param h: (B, feature_dim) features of the context.
        :param future_actions: (B, T, action_dim) actions from the context on, T >= max(steps).
        :param steps: (B,) rollout lengths k >= 1, from ``draw_steps``.
        :param target: (B, C, h, w) frame at step k, uint8 in [0, 255] or float in [0, 1], shifted with the context.
        :param valid: optional (B,) bool or float weights; samples with ``valid == 0`` contribute nothing.
        :param skip: encoder feature map of the context when ``skip_channels > 0``.
        :return: a scalar; 0 (still differentiable) when no sample is valid.
        """
        batch = h.shape[0]
        h_scene, h_agent = self.split(h)
        if steps.shape != (batch,) or steps.dtype not in (th.int32, th.int64):
            raise ValueError(f"Expected integer steps of shape ({batch},), got {tuple(steps.shape)} {steps.dtype}")
        if future_actions.dim() != 3 or future_actions.shape[0] != batch:
            raise ValueError(
                f"Expected future_actions of shape ({batch}, steps, {self.action_dim}), "
                f"got {tuple(future_actions.shape)}"
            )
        if th.compiler.is_compiling():
            # Static shapes, no device sync: roll out the whole window (the prediction at each k is the same).
            max_step = future_actions.shape[1]
        else:
            min_step, max_step = th.stack(th.aminmax(steps)).tolist()  # one device sync for both bounds
            if min_step < 1 or max_step > future_actions.shape[1]:
                raise ValueError(f"steps must lie in [1, {future_actions.shape[1]}], got [{min_step}, {max_step}]")
        if valid is not None and valid.shape != (batch,):
            raise ValueError(f"Expected valid of shape ({batch},), got {tuple(valid.shape)}")
        target = self._target_to_float(target, batch)
        if self.decode_batch_size is not None and batch > self.decode_batch_size:
            batch = self.decode_batch_size
            h_scene, h_agent, future_actions, steps, target = (
                x[:batch] for x in (h_scene, h_agent, future_actions, steps, target)
            )
            valid = None if valid is None else valid[:batch]
            skip = None if skip is None else skip[:batch]
        agent_states = self.rollout(h_agent, future_actions[:, :max_step])
        predicted_agent = agent_states[th.arange(batch, device=h.device), steps.long() - 1]
        prediction = self.decode(h_scene, predicted_agent, skip)
        per_sample = (prediction - target).pow(2).flatten(1).sum(dim=1)
        if valid is None:
            return per_sample.mean()
        weights = valid.to(per_sample.dtype)
        return (per_sample * weights).sum() / weights.sum().clamp(min=1.0)

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
        """Check the target frame's shape and bring it to float in [0, 1]."""
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
