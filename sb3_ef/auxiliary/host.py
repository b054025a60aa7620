"""What every sb3-ef host algorithm shares: the host side of the auxiliary-loss interface.

:class:`AuxiliaryHostMixin` is mixed into every host (DrQ-v2, TD-MPC2, and SB3's SAC / TD3 / TQC through
:class:`~sb3_ef.auxiliary.step.AuxiliaryStepMixin`): the sequence replay buffer; an optional auxiliary
representation loss on the host's encoder (an :class:`~sb3_ef.auxiliary.loss.AuxiliaryLoss` that a subclass returns
from ``_build_auxiliary``, kept where ``_keep_auxiliary`` puts it and trained by the optimiser the host names in
``_optimise_auxiliary``); motor babbling (a :class:`~sb3_ef.ef.babbling.MotorBabblingCallback` added to ``learn``'s
callbacks); the accessors ``ef`` / ``encode`` / ``frame_shape`` read by ``sb3_ef.analysis``; the finite-loss check;
logging; and a ``load`` that refuses a file another algorithm saved and reads those saved by sb3-ef 0.1.0
(:mod:`sb3_ef.ef.legacy`).
"""

from __future__ import annotations

import io
import json
import pathlib
import warnings
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.save_util import open_path
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.env_checks import FRAME_CHANNELS, check_sequence_buffer
from sb3_ef.common.validation import (
    check_learn,
    check_model_path,
    check_observation,
    check_saved_algorithm,
)
from sb3_ef.ef.babbling import MotorBabblingCallback, with_babbling
from sb3_ef.ef.foresight import EgoForesight, ForesightLoss
from sb3_ef.ef.legacy import upgraded_file, upgraded_parameters

SelfHost = TypeVar("SelfHost", bound="AuxiliaryHostMixin")


@contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Inside the block ``module``'s parameters take no gradient: a loss computed through it trains only what comes
    before it (an actor through its critic). Kept out of compiled functions."""
    module.requires_grad_(False)
    try:
        yield
    finally:
        module.requires_grad_(True)


def saved_algorithm(path: str | pathlib.Path | io.BufferedIOBase) -> str | None:
    """The class name of the algorithm that saved a model file, or ``None`` when the file does not record one."""
    file = open_path(path, "r", verbose=0, suffix="zip")
    position = file.tell()
    try:
        with zipfile.ZipFile(file) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError):
        return None  # SB3's load reports what is wrong with the file
    finally:
        if isinstance(path, io.BufferedIOBase):
            file.seek(position)
        else:
            file.close()
    name = data.get("algorithm")
    return name if isinstance(name, str) else None


class AuxiliaryHostMixin:
    """Mixed in first by every host algorithm (``class DrQv2(AuxiliaryHostMixin, OffPolicyAlgorithm)``).

    The host calls :meth:`_use_sequence_buffer` before ``super()._setup_model()``, and in its update
    :meth:`_augment_observations` (the observations it encodes, and the auxiliary loss's targets), then adds
    ``self.auxiliary(features, targets)`` to the loss that trains its encoder (or steps it on its own optimiser) and
    calls ``auxiliary.after_update(encoder)`` after its optimiser steps. A subclass supplies the auxiliary loss by
    overriding :meth:`_build_auxiliary` (and :meth:`_auxiliary_horizon` when the loss reads future steps); the host
    says in :meth:`_optimise_auxiliary` which optimiser trains it. Babbling needs nothing from the host: with
    ``babbling_steps > 0``, ``learn`` runs a :class:`MotorBabblingCallback` of those steps before the caller's
    callbacks (its state is saved with the model).
    """

    policy: Any
    env: VecEnv | None
    logger: Logger
    seed: int | None
    device: th.device
    num_timesteps: int
    observation_space: spaces.Space
    action_space: spaces.Space
    replay_buffer_class: type[ReplayBuffer] | None
    replay_buffer_kwargs: dict[str, Any]
    _n_updates: int

    #: The class name, saved with the model: ``load`` refuses a file saved by another algorithm.
    algorithm: str
    babbling_steps: int = 0
    babbling_mode: str = "sign"
    babbling_in_eval: bool = False
    check_finite_losses: bool = False
    # Generator of the auxiliary loss's draws; created in ``_setup_model`` from the seed, saved with the model so
    # that a resumed run continues its stream.
    _auxiliary_generator: th.Generator | None = None

    def _build_auxiliary(self) -> AuxiliaryLoss | None:
        """The auxiliary loss on this host's encoder, built after the policy (``None``: the plain algorithm)."""
        return None

    def _auxiliary_horizon(self) -> int:
        """Steps after t of each replay sample that the auxiliary loss reads (the buffer's window); 0 for none."""
        return 0

    def _optimise_auxiliary(self, auxiliary: AuxiliaryLoss) -> None:
        """Give the auxiliary module's parameters to the optimiser that trains them (each host decides)."""
        raise NotImplementedError(f"{type(self).__name__} does not say which optimiser trains its auxiliary loss")

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
        that ``n_steps`` is ignored does not apply), then the auxiliary loss (moved to the model's device, kept
        where :meth:`_keep_auxiliary` says, given to its optimiser), then the generator unless it was loaded."""
        self.algorithm = type(self).__name__
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"`n_steps=\d+` is ignored because a custom")
            super()._setup_model()  # type: ignore[misc]
        auxiliary = self._build_auxiliary()
        if auxiliary is not None:
            self._keep_auxiliary(auxiliary.to(self.device))
            self._optimise_auxiliary(auxiliary)
        if self._auxiliary_generator is None:
            # On the CPU, so that a saved model loads on any device.
            self._auxiliary_generator = th.Generator()
            self._auxiliary_generator.manual_seed(int(np.random.randint(2**31)) if self.seed is None else self.seed)

    def _keep_auxiliary(self, auxiliary: AuxiliaryLoss) -> None:
        """Keep the auxiliary module where it is saved with the model: on the policy (``policy.auxiliary``)."""
        self.policy.auxiliary = auxiliary

    @property
    def auxiliary(self) -> AuxiliaryLoss | None:
        """The auxiliary loss module (``policy.auxiliary``), or ``None`` for the plain algorithm."""
        return getattr(getattr(self, "policy", None), "auxiliary", None)

    @property
    def ef(self) -> EgoForesight | None:
        """The Ego-Foresight module when the auxiliary loss is EF's, else ``None``."""
        auxiliary = self.auxiliary
        return auxiliary.ef if isinstance(auxiliary, ForesightLoss) else None

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """Shape ``(3, height, width)`` of one RGB frame of the stacked observations."""
        _, height, width = self.observation_space.shape  # type: ignore[misc]
        return (FRAME_CHANNELS, height, width)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of uint8 stacked observations (no augmentation; gradients flow if the caller wants them)."""
        return self.policy.encode(observations.to(self.device))

    def _augment_observations(self, batch: SequenceReplayBufferSamples, pad: int) -> tuple[th.Tensor, Any]:
        """The observations at t as the host encodes them, and the auxiliary loss's targets (``None`` without one).
        Without an auxiliary loss, a random shift of ``pad`` pixels; with one, its ``prepare`` augments (shifting
        its targets along), drawing its own random numbers from the model's generator."""
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

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """SB3's ``predict``, refusing an observation that is not the env's uint8 frames with a clear error."""
        check_observation(observation, self.observation_space)
        return super().predict(observation, state, episode_start, deterministic)  # type: ignore[misc]

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
        return super().learn(  # type: ignore[misc]
            total_timesteps=total_timesteps,
            callback=callback,
            log_interval=log_interval,
            tb_log_name=tb_log_name or type(self).__name__,
            reset_num_timesteps=reset_num_timesteps,
            progress_bar=progress_bar,
        )

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
        """SB3's ``load``; a missing or damaged file is named at once, and a file that another algorithm saved is
        refused (a ``DrQv2EF`` file read as ``DrQv2`` would carry EF's weights the plain class does not have): by the
        algorithm the file records, or, for a file that records none, by its policy class."""
        from sb3_ef.ef.host import EFMixin  # the 0.1.0 upgrade differs for EF's hosts

        zip_path = check_model_path(path)
        saved = saved_algorithm(path)
        if saved is not None and saved != cls.__name__:
            raise ValueError(f"Cannot load {path} as {cls.__name__}: it was saved by {saved}, use {saved}.load")
        if saved is None:
            check_saved_algorithm(cls, zip_path)
        return super().load(  # type: ignore[misc]
            upgraded_file(path, cls, issubclass(cls, EFMixin), custom_objects),  # as saved by this version
            env,
            device,
            custom_objects,
            print_system_info,
            force_reset,
            **kwargs,
        )

    def set_parameters(
        self,
        load_path_or_dict: str | pathlib.Path | io.BufferedIOBase | dict[str, Any],
        exact_match: bool = True,
        device: th.device | str = "auto",
    ) -> None:
        """SB3's ``set_parameters``; the weights and optimiser states of a model saved by sb3-ef 0.1.0 are first
        moved to where this version keeps them (:mod:`sb3_ef.ef.legacy`)."""
        params = upgraded_parameters(load_path_or_dict, self, device)
        super().set_parameters(params, exact_match, device)  # type: ignore[misc]
