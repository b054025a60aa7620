"""What makes a host an Ego-Foresight variant: :class:`EFBaseMixin` keeps EF's arguments and reads ``beta`` and ``ef``
through to the loss (every EF host); :class:`EFMixin` adds the off-policy hosts' loss and motor babbling callback."""

from __future__ import annotations

import numbers
from typing import Any

import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import MaybeCallback
from torch import nn

from sb3_ef.auxiliary.host import AuxiliaryHostMixin
from sb3_ef.common.env_checks import episode_steps
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.ef.arguments import check_ef_kwargs
from sb3_ef.ef.babbling import MotorBabblingCallback, check_babbling, with_babbling
from sb3_ef.ef.foresight import EgoForesight
from sb3_ef.ef.latent import feed_encoder
from sb3_ef.ef.losses import Encode, ForesightLoss, foresight_loss


def check_ef_arguments(
    beta: float, ef_horizon: int, babbling_steps: int, babbling_mode: str, plain_variant: str
) -> None:
    """Check EF's algorithm-level arguments; ``plain_variant`` names the class to use without EF."""
    check_babbling(babbling_steps, babbling_mode)
    check_beta(beta, plain_variant)
    if not isinstance(ef_horizon, int) or ef_horizon < 1:
        raise ValueError(f"ef_horizon must be a positive integer, got {ef_horizon!r}")


def check_beta(beta: float, plain_variant: str) -> None:
    """Check EF's loss weight; ``plain_variant`` names the class to use without EF."""
    if isinstance(beta, bool) or not isinstance(beta, numbers.Real) or not beta > 0:
        received = (
            repr(beta)
            if isinstance(beta, numbers.Real) and not isinstance(beta, bool)
            else f"{type(beta).__name__} {beta!r}"
        )
        raise ValueError(
            f"beta must be a positive number (use {plain_variant} to train without Ego-Foresight), got {received}"
        )


def check_horizon_fits_episodes(ef_horizon: int | None, steps: int | None) -> None:
    if ef_horizon is not None and steps is not None and ef_horizon > steps:
        raise ValueError(
            f"ef_horizon must not exceed the episode length: expected ef_horizon <= {steps}, got {ef_horizon}"
        )


class EFPolicyMixin:
    """Mixed in before a host's policy to make its EF policy: keeps and saves ``agent_dim`` and ``ef_kwargs``."""

    def __init__(self, *args: Any, agent_dim: int = 32, ef_kwargs: dict[str, Any] | None = None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        self.agent_dim = agent_dim
        self.ef_kwargs = ef_kwargs or {}

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()  # type: ignore[misc]
        return {**data, "agent_dim": self.agent_dim, "ef_kwargs": self.ef_kwargs}


class EFBaseMixin(AuxiliaryHostMixin):
    """What every Ego-Foresight host shares, off-policy (:class:`EFMixin`) or on-policy (``OnPolicyEFMixin``): EF's
    algorithm-level arguments checked and kept, ``model.beta`` and ``model.ef`` read through to the loss."""

    ef_horizon: int
    babbling_steps: int = 0
    babbling_mode: str = "sign"
    # ``beta`` as given to the constructor, until the loss that keeps it is built.
    _beta: float

    @property
    def beta(self) -> float:
        """Weight of EF's loss, kept once, as a buffer of the loss module; setting it changes the next updates."""
        auxiliary = self.auxiliary
        return float(auxiliary.beta) if isinstance(auxiliary, ForesightLoss) else self._beta

    @beta.setter
    def beta(self, value: float) -> None:
        check_beta(value, self._plain_variant().__name__)
        auxiliary = self.auxiliary
        if isinstance(auxiliary, ForesightLoss):
            auxiliary.beta.fill_(value)
        else:
            self._beta = value

    @property
    def ef(self) -> EgoForesight | None:
        """The Ego-Foresight module (read by ``sb3_ef.analysis``); ``None`` before the model is set up."""
        auxiliary = self.auxiliary
        return auxiliary.ef if isinstance(auxiliary, ForesightLoss) else None

    def _plain_variant(self) -> type:
        """The host without EF (named by the errors that say how to train without it)."""
        return next(c for c in type(self).__mro__ if issubclass(c, BaseAlgorithm) and not issubclass(c, EFBaseMixin))

    def _keep_ef_arguments(
        self, beta: float, ef_horizon: int, babbling_steps: int, babbling_mode: str, ef_kwargs: dict[str, Any] | None
    ) -> None:
        """Check and keep EF's arguments (``ef_kwargs`` checked before any network is built, kept by the caller)."""
        check_ef_kwargs(ef_kwargs or {})
        check_ef_arguments(beta, ef_horizon, babbling_steps, babbling_mode, self._plain_variant().__name__)
        self._beta = beta
        self.ef_horizon = ef_horizon
        self.babbling_steps = babbling_steps
        self.babbling_mode = babbling_mode

    def _foresight_loss(
        self,
        encoder: nn.Module,
        feature_dim: int,
        agent_dim: int,
        ef_kwargs: dict[str, Any] | None,
        channels_last: bool = False,
        encode: Encode = feed_encoder,
        action_dim: int | None = None,
    ) -> ForesightLoss:
        """EF's loss (pixel or latent, as ``ef_kwargs`` says) on ``encoder``, fed as ``encode`` says, reading actions
        of ``action_dim`` (``None``: the Box action space's size); it takes ``beta`` over from the constructor's
        argument and keeps it from then on."""
        if action_dim is None:
            action_dim = int(np.prod(self.action_space.shape))  # type: ignore[arg-type]
        loss = foresight_loss(
            feature_dim, action_dim, self.frame_shape, agent_dim, self.ef_horizon, self._beta, ef_kwargs,
            channels_last, encoder, encode,
        )  # fmt: skip
        del self._beta
        return loss


class EFMixin(EFBaseMixin):
    """Mixed in before a plain off-policy host to make its Ego-Foresight variant (``class DrQv2EF(EFMixin, DrQv2)``):
    :class:`EFBaseMixin`'s arguments with ``babbling_in_eval``, EF's window in the replay buffer and the babbling
    callback. The variant's ``_build_auxiliary`` builds the loss with :meth:`_foresight_loss` on the encoder EF
    trains; the host's ``_setup_model`` gives it to an optimiser and its ``train`` calls it, as for any auxiliary
    loss."""

    babbling_in_eval: bool = False

    def _init_ef(
        self,
        beta: float,
        ef_horizon: int,
        babbling_steps: int,
        babbling_mode: str,
        babbling_in_eval: bool,
        ef_kwargs: dict[str, Any] | None,
    ) -> None:
        """:meth:`_keep_ef_arguments`, and ``babbling_in_eval``."""
        check_algorithm_arguments(type(self), {"ef_horizon": ef_horizon, "babbling_steps": babbling_steps})
        self._keep_ef_arguments(beta, ef_horizon, babbling_steps, babbling_mode, ef_kwargs)
        self.babbling_in_eval = babbling_in_eval

    def _auxiliary_horizon(self) -> int:
        return self.ef_horizon

    def _init_callback(self, callback: MaybeCallback, progress_bar: bool = False) -> BaseCallback:
        """SB3's, with the :class:`MotorBabblingCallback` first when babbling is on."""
        if self.babbling_steps > 0:
            babbling = MotorBabblingCallback(self.babbling_steps, self.babbling_mode, self.babbling_in_eval)
            babbling.warn_if_late = False
            callback = with_babbling(babbling, callback)
        return super()._init_callback(callback, progress_bar)  # type: ignore[misc]

    def _setup_model(self) -> None:
        """Check that EF's window fits in an episode (here, so that ``load`` checks it too), then the host's setup."""
        if self.env is not None:
            check_horizon_fits_episodes(self.ef_horizon, episode_steps(self.env))
        super()._setup_model()

    def _ef_policy(self) -> Any:
        """The policy, checked to be the host's EF policy (it carries ``agent_dim`` and ``ef_kwargs``)."""
        policy, expected = self.policy, self.policy_aliases["CnnPolicy"]  # type: ignore[attr-defined]
        if not isinstance(policy, expected):
            name = type(self).__name__
            raise TypeError(f"{name} needs a {expected.__name__} (EF's sizes), got {type(policy).__name__}")
        return policy
