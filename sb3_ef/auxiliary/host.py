"""The host side of the auxiliary-loss interface, shared by every host, and the ``aux_grad_ratio`` diagnostic."""

from __future__ import annotations

import io
import pathlib
from collections.abc import Iterable
from typing import Any, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.exploration import ActionOverrideMixin
from sb3_ef.common.interrupt import progress_bar_callback
from sb3_ef.common.precision import check_precision
from sb3_ef.common.saved_models import check_saved_model, save_model_atomically, saved_data
from sb3_ef.common.validation import check_learn, check_model_path, check_observation

SelfHost = TypeVar("SelfHost", bound="AuxiliaryHostMixin")
#: One update in this many measures the encoder-gradient ratio behind ``train/aux_grad_ratio``.
AUX_GRAD_RATIO_EVERY = 100
#: ``train/aux_grad_ratio`` is an exponential average of the measured ratios, the newest weighted this much.
AUX_GRAD_RATIO_WEIGHT = 0.2


def aux_grad_ratio_due(n_updates: int, every: int = AUX_GRAD_RATIO_EVERY) -> bool:
    """Whether update number ``n_updates`` (counted from 1) computes the ratio: the first, then one in ``every``."""
    return n_updates % every == 1 or every == 1


def encoder_gradient_ratio(
    auxiliary_loss: th.Tensor, host_loss: th.Tensor, parameters: Iterable[nn.Parameter]
) -> th.Tensor:
    """``||d aux / d encoder|| / ||d host / d encoder||`` by two extra backward passes, graphs kept; detached."""
    params = [param for param in parameters if param.requires_grad]
    norms = [
        _norm(th.autograd.grad(loss, params, retain_graph=True, allow_unused=True), loss.device)
        for loss in (auxiliary_loss, host_loss)
    ]
    return norms[0] / norms[1].clamp_min(1e-12)


def gradient_norm(parameters: Iterable[nn.Parameter]) -> th.Tensor:
    """The 2-norm of the ``.grad`` the last backward pass left on ``parameters`` (none counts as 0), detached."""
    params = list(parameters)
    return _norm([param.grad for param in params], params[0].device if params else th.device("cpu"))


def gradient_norm_ratio(parameters: Iterable[nn.Parameter], host_norm: th.Tensor) -> th.Tensor:
    """:func:`gradient_norm` of ``parameters`` over ``host_norm``: the ratio for an auxiliary step of its own."""
    return gradient_norm(parameters) / host_norm.clamp_min(1e-12)


def _norm(grads: Iterable[th.Tensor | None], device: th.device) -> th.Tensor:
    squares = [grad.detach().pow(2).sum() for grad in grads if grad is not None]
    return th.stack(squares).sum().sqrt() if squares else th.zeros((), device=device)


class AuxiliaryHostMixin(ActionOverrideMixin):
    """What every host shares, whatever its update (``class DrQv2(AuxiliaryHostMixin, OffPolicyAlgorithm)``).

    The host owns its update: its ``_setup_model`` builds the auxiliary loss (:meth:`_build_auxiliary`, ``None`` for
    the plain algorithm) and gives its parameters to one of its optimisers; its ``train`` calls the loss's
    ``prepare``, ``forward`` and ``after_update`` (:class:`~sb3_ef.auxiliary.loss.AuxiliaryLoss`) around its own
    steps. This class keeps what is the same for every host: the model's draws for the loss, ``encode``,
    ``frame_shape``, the finite-loss check, the logs of an update, and SB3's ``learn`` / ``predict`` / ``save`` /
    ``load`` with the package's checks.
    """

    policy: Any
    env: VecEnv | None
    logger: Logger
    seed: int | None
    device: th.device
    num_timesteps: int
    observation_space: spaces.Space
    action_space: spaces.Space
    _n_updates: int

    #: The class name, saved with the model: ``load`` refuses a file saved by another algorithm.
    algorithm: str
    check_finite_losses: bool = False
    #: ``"fp32"`` or ``"bf16"`` (:mod:`sb3_ef.common.precision`); files saved without it load as ``"fp32"``.
    precision: str = "fp32"
    # The auxiliary loss's draws, saved with the model so that a resumed run continues its stream.
    _auxiliary_generator: th.Generator | None = None
    # The exponential average of the measured ``aux_grad_ratio`` values (a diagnostic, not saved).
    _aux_grad_ratio_average: th.Tensor | None = None

    def _build_auxiliary(self) -> AuxiliaryLoss | None:
        """The auxiliary loss on this host's encoder, built after the policy (``None``: the plain algorithm)."""
        return None

    def _auxiliary_horizon(self) -> int:
        """Steps after t of each sample that the auxiliary loss reads (the buffer's window); 0 for none."""
        return 0

    def _setup_model(self) -> None:
        """SB3's ``_setup_model`` (``precision`` checked against the device, also on ``load``), then the auxiliary
        loss's random generator (seeded from ``seed``)."""
        self.algorithm = type(self).__name__
        check_precision(self.precision, self.device)
        super()._setup_model()  # type: ignore[misc]
        if self._auxiliary_generator is None:
            # On the CPU, so that a saved model loads on any device.
            self._auxiliary_generator = th.Generator()
            self._auxiliary_generator.manual_seed(int(np.random.randint(2**31)) if self.seed is None else self.seed)

    @property
    def auxiliary(self) -> AuxiliaryLoss | None:
        """The auxiliary loss module (``policy.auxiliary``), or ``None`` for the plain algorithm."""
        return getattr(getattr(self, "policy", None), "auxiliary", None)

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape ``(3, height, width)`` of one RGB frame of the stacked observations."""
        _, height, width = self.observation_space.shape  # type: ignore[misc]
        return (FRAME_CHANNELS, height, width)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of uint8 stacked observations (no augmentation; gradients flow if the caller wants them)."""
        return self.policy.encode(observations.to(self.device))

    def _augment_observations(self, batch: SequenceReplayBufferSamples, pad: int) -> tuple[th.Tensor, Any]:
        """The observations at t as the host encodes them, and the auxiliary loss's targets (``None`` without one)."""
        if self.auxiliary is None:
            (observations,) = random_shift(batch.observations, pad=pad)
            return observations, None
        return self.auxiliary.prepare(batch, pad, self._auxiliary_generator)

    def _check_finite(self, **losses: th.Tensor) -> None:
        """With ``check_finite_losses``, raise before an optimiser step if a loss is NaN or infinite."""
        if not self.check_finite_losses:
            return
        for name, loss in losses.items():
            if not bool(th.isfinite(loss).all()):
                raise ValueError(f"{name} is {loss.item()} at update {self._n_updates}")

    def _averaged_aux_grad_ratio(self, ratio: th.Tensor) -> th.Tensor:
        """The exponential average of the ratios measured so far, ``ratio`` weighted :data:`AUX_GRAD_RATIO_WEIGHT`."""
        previous = self._aux_grad_ratio_average
        average = ratio if previous is None else previous + AUX_GRAD_RATIO_WEIGHT * (ratio - previous)
        self._aux_grad_ratio_average = average.detach()
        return self._aux_grad_ratio_average

    def _record_updates(self, updates: list[dict[str, th.Tensor]]) -> None:
        """Log each scalar of the updates as ``train/<key>``, averaged over the updates that computed it."""
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key in dict.fromkeys(key for update in updates for key in update):
            values = th.stack([update[key].detach().reshape(()) for update in updates if key in update])
            self.logger.record(f"train/{key}", float(values.double().mean()))

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``, refusing an observation that is not the env's uint8 frames with a clear error."""
        check_observation(observation, self.observation_space)
        return super().predict(observation, state, episode_start, deterministic)

    def learn(
        self: SelfHost,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 4,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfHost:
        """SB3's ``learn``; ``tb_log_name`` defaults to the class name (so plain and EF variants log apart)."""
        check_learn(self, total_timesteps, reset_num_timesteps)
        with progress_bar_callback(callback, progress_bar) as callback:
            return super().learn(  # type: ignore[misc]
                total_timesteps=total_timesteps,
                callback=callback,
                log_interval=log_interval,
                tb_log_name=tb_log_name or type(self).__name__,
                reset_num_timesteps=reset_num_timesteps,
                progress_bar=False,
            )

    def save(
        self,
        path: str | pathlib.Path | io.BufferedIOBase,
        exclude: Iterable[str] | None = None,
        include: Iterable[str] | None = None,
    ) -> None:
        """SB3's ``save``, written whole or not at all (a temporary file beside the target, fsynced, renamed)."""
        save_model_atomically(super().save, path, exclude, include)  # type: ignore[misc]

    @classmethod
    def load(
        cls: type[SelfHost],
        path: str | pathlib.Path | io.BufferedIOBase,
        env: GymEnv | None = None,
        device: th.device | str = "auto",
        custom_objects: dict[str, Any] | None = None,
        print_system_info: bool = False,
        force_reset: bool = True,
        **kwargs: Any,
    ) -> SelfHost:
        """SB3's ``load``, refusing a missing, damaged or foreign file with what to do instead."""
        check_model_path(path)
        data = saved_data(path)
        check_saved_model(cls, path, data)
        if data is not None and isinstance(kwargs.get("policy_kwargs"), dict):
            kwargs["policy_kwargs"] = cls._completed_policy_kwargs(kwargs["policy_kwargs"], data)
        return super().load(  # type: ignore[misc]
            path, env, device, custom_objects, print_system_info, force_reset, **kwargs
        )

    @classmethod
    def _completed_policy_kwargs(cls, policy_kwargs: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
        """``load``'s ``policy_kwargs`` with the entries the constructor adds, so that SB3's comparison holds."""
        return policy_kwargs
