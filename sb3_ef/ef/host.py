"""Ego-Foresight's integration into a host algorithm, in one place.

A host is an SB3 ``OffPolicyAlgorithm`` whose policy has an encoder and, when EF is on, an ``ef`` module (``None``
when off: that is the only switch). :class:`EFHostMixin` gives it EF's training step (the window: rollout length k,
frame t+k shifted together with the context, validity), the EF loss, motor babbling (a
:class:`~sb3_ef.ef.babbling.MotorBabblingCallback` added to ``learn``'s callbacks), the sequence replay buffer, the
accessors ``ef`` / ``encode`` / ``frame_shape`` read by ``sb3_ef.analysis``, and the optional finite-loss check.
:func:`build_ef` builds the EF module for a policy.
"""

from __future__ import annotations

import inspect
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import MaybeCallback

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.env_checks import FRAME_CHANNELS, check_sequence_buffer
from sb3_ef.ef.babbling import MotorBabblingCallback, check_babbling, with_babbling
from sb3_ef.ef.foresight import EgoForesight

SelfEFHost = TypeVar("SelfEFHost", bound="EFHostMixin")
# The arguments through which a host algorithm takes Ego-Foresight (a plain variant takes none of them).
EF_ARGUMENTS = ("beta", "ef_horizon", "babbling_steps", "babbling_mode", "babbling_in_eval")


class EFWindow(NamedTuple):
    """What one EF loss needs from a replay batch: rollout lengths k, the (shifted) frames t+k and their validity."""

    steps: th.Tensor
    target: th.Tensor
    valid: th.Tensor


def build_ef(
    feature_dim: int,
    action_dim: int,
    frame_shape: tuple[int, int, int],
    agent_dim: int,
    horizon: int | None,
    ef_kwargs: dict[str, Any] | None = None,
    channels_last: bool = True,
) -> EgoForesight | None:
    """The EF module of a policy whose encoder gives ``feature_dim`` features; ``None`` when ``horizon`` is ``None``
    (EF off). ``channels_last`` keeps the decoder's conv weights in channels-last memory format (same maths,
    faster convolutions)."""
    if horizon is None:
        return None
    if feature_dim <= agent_dim:
        raise ValueError(
            f"Ego-Foresight needs features_dim > agent_dim (scene features must remain), "
            f"got features_dim={feature_dim}, agent_dim={agent_dim}"
        )
    ef = EgoForesight(
        feature_dim, action_dim, frame_shape=frame_shape, agent_dim=agent_dim, horizon=horizon, **(ef_kwargs or {})
    )
    if channels_last:
        ef.to(memory_format=th.channels_last)  # type: ignore[call-overload]
    return ef


def check_ef_arguments(
    beta: float | None, ef_horizon: int | None, babbling_steps: int, babbling_mode: str, plain_variant: str
) -> None:
    """Check EF's algorithm-level arguments; ``plain_variant`` names the class to use without EF (which passes
    ``beta=None, ef_horizon=None``)."""
    check_babbling(babbling_steps, babbling_mode)
    if beta is None and ef_horizon is None:
        return
    if beta is None or not beta > 0:
        raise ValueError(
            f"beta must be a positive number (use {plain_variant} to train without Ego-Foresight), got {beta!r}"
        )
    if not isinstance(ef_horizon, int) or ef_horizon < 1:
        raise ValueError(f"ef_horizon must be a positive integer, got {ef_horizon!r}")


def check_horizon_fits_episodes(ef_horizon: int | None, steps: int | None) -> None:
    if ef_horizon is not None and steps is not None and ef_horizon > steps:
        raise ValueError(
            f"ef_horizon must not exceed the episode length: expected ef_horizon <= {steps}, got {ef_horizon}"
        )


def plain_variant_kwargs(kwargs: dict[str, Any], plain_variant: str, ef_variant: str) -> dict[str, Any]:
    """The arguments a plain variant (EF off) gives its EF class: the caller's, with EF switched off. EF's own
    arguments are rejected as Python rejects an unknown keyword."""
    given = sorted(set(kwargs) & set(EF_ARGUMENTS))
    if given:
        raise TypeError(
            f"{plain_variant} got Ego-Foresight arguments {given}: {plain_variant} trains without EF, use {ef_variant}"
        )
    return {**kwargs, "beta": None, "ef_horizon": None, "babbling_steps": 0}


def plain_variant_signature(ef_init: Callable[..., None]) -> inspect.Signature:
    """The signature of a plain variant's ``__init__``: its EF class's, without EF's arguments (what
    ``inspect.signature`` shows users and what rl-zoo3 configs are checked against)."""
    signature = inspect.signature(ef_init)
    return signature.replace(parameters=[p for p in signature.parameters.values() if p.name not in EF_ARGUMENTS])


class EFHostMixin:
    """Mixed in first (``class Host(EFHostMixin, OffPolicyAlgorithm)``) by every algorithm that trains EF.

    The host calls :meth:`_init_ef` in ``__init__``, :meth:`_use_sequence_buffer` before ``super()._setup_model()``
    and, in its update, :meth:`_ef_window` (the context it encodes, and the EF window) and :meth:`_ef_loss`.
    Babbling needs nothing from the host: with ``babbling_steps > 0``, ``learn`` runs a
    :class:`MotorBabblingCallback` of those steps before the caller's callbacks (its state is saved with the model).
    """

    policy: Any
    logger: Logger
    seed: int | None
    device: th.device
    num_timesteps: int
    observation_space: spaces.Space
    action_space: spaces.Space
    replay_buffer_class: type[ReplayBuffer] | None
    replay_buffer_kwargs: dict[str, Any]
    _n_updates: int

    beta: float | None = None
    ef_horizon: int | None = None
    babbling_steps: int = 0
    babbling_mode: str = "sign"
    babbling_in_eval: bool = False
    check_finite_losses: bool = False
    # Generator of EF's rollout lengths; created in ``_setup_model`` from the seed, saved with the model so that a
    # resumed run continues its stream.
    _ef_generator: th.Generator | None = None

    def _init_ef(
        self,
        beta: float | None,
        ef_horizon: int | None,
        babbling_steps: int,
        babbling_mode: str,
        babbling_in_eval: bool,
        check_finite_losses: bool,
        plain_variant: str,
    ) -> None:
        """Check and keep EF's algorithm-level arguments (``beta=None, ef_horizon=None``: EF off)."""
        check_ef_arguments(beta, ef_horizon, babbling_steps, babbling_mode, plain_variant)
        self.beta = beta
        self.ef_horizon = ef_horizon
        self.babbling_steps = babbling_steps
        self.babbling_mode = babbling_mode
        self.babbling_in_eval = babbling_in_eval
        self.check_finite_losses = check_finite_losses

    def _use_sequence_buffer(self, why: str, horizon: int, **defaults: Any) -> None:
        """Make SB3's ``_setup_model`` build a :class:`SequenceReplayBuffer` with a window of ``horizon`` steps;
        ``defaults`` (``n_steps``, ``gamma``) apply unless ``replay_buffer_kwargs`` sets them. ``why`` says what the
        host samples that only this buffer provides (the error message for another buffer class)."""
        check_sequence_buffer(self.replay_buffer_class, why)
        if self.replay_buffer_class is None:
            self.replay_buffer_class = SequenceReplayBuffer
        self.replay_buffer_kwargs = {**defaults, **self.replay_buffer_kwargs, "horizon": horizon}

    def _setup_model(self) -> None:
        """SB3's ``_setup_model`` (the buffer's n-step returns are configured through its kwargs, so SB3's warning
        that ``n_steps`` is ignored does not apply), then EF's generator unless it was loaded."""
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom")
            super()._setup_model()  # type: ignore[misc]
        if self._ef_generator is None:
            # On the CPU, so that a saved model loads on any device.
            self._ef_generator = th.Generator()
            self._ef_generator.manual_seed(int(np.random.randint(2**31)) if self.seed is None else self.seed)

    @property
    def ef(self) -> EgoForesight | None:
        """The Ego-Foresight module, or ``None`` when EF is off."""
        return self.policy.ef

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape ``(3, height, width)`` of one RGB frame of the stacked observations."""
        _, height, width = self.observation_space.shape  # type: ignore[misc]
        return (FRAME_CHANNELS, height, width)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of uint8 stacked observations (no augmentation; gradients flow if the caller wants them)."""
        return self.policy.encode(observations.to(self.device))

    def _ef_window(self, batch: SequenceReplayBufferSamples, pad: int) -> tuple[th.Tensor, EFWindow | None]:
        """Random-shift the observations at t; with EF, draw the rollout lengths k (own generator, so EF leaves the
        host's random draws unchanged) and shift frame t+k together with its context. The window is ``None`` when
        EF is off."""
        if self.ef is None:
            (observations,) = random_shift(batch.observations, pad=pad)
            return observations, None
        steps = self.ef.draw_steps(batch.future_mask, generator=self._ef_generator)
        rows = th.arange(steps.shape[0], device=steps.device)
        observations, target = random_shift(batch.observations, batch.future_frames[rows, steps - 1], pad=pad)
        return observations, EFWindow(steps, target, batch.future_mask[rows, steps - 1])

    def _ef_loss(self, features: th.Tensor, future_actions: th.Tensor, window: EFWindow | None) -> th.Tensor | None:
        """EF's loss (unweighted) for features of the window's context: roll the agent features k actions ahead and
        reconstruct frame t+k. ``None`` without a window (EF off)."""
        if window is None:
            return None
        assert self.ef is not None
        return self.ef.loss(features, future_actions, window.steps, window.target, window.valid)

    def _check_finite(self, **losses: th.Tensor) -> None:
        """With ``check_finite_losses``, raise before an optimiser step if a loss is NaN or infinite."""
        if not self.check_finite_losses:
            return
        for name, loss in losses.items():
            if not bool(th.isfinite(loss).all()):
                raise ValueError(f"{name} is {loss.item()} at update {self._n_updates}")

    def _record_updates(self, updates: list[dict[str, th.Tensor]]) -> None:
        """Log each scalar of the updates (``train/<key>``), averaged over the gradient steps."""
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key in updates[0] if updates else ():
            values = th.stack([update[key].detach().reshape(()) for update in updates])
            self.logger.record(f"train/{key}", float(values.double().mean()))

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        """SB3's, with the :class:`MotorBabblingCallback` of ``babbling_steps`` first when babbling is on."""
        if self.babbling_steps > 0:
            babbling = MotorBabblingCallback(self.babbling_steps, self.babbling_mode, self.babbling_in_eval)
            callback = with_babbling(babbling, callback)
        return super()._init_callback(callback, progress_bar)  # type: ignore[misc]

    def learn(
        self: SelfEFHost,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfEFHost:
        """SB3's ``learn``; ``tb_log_name`` defaults to the class name (so plain and EF variants log apart)."""
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )
