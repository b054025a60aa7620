"""An auxiliary representation loss on an SB3 off-policy algorithm from pixels (SAC, TD3, TQC), as a step of its own
after each of the host's updates: SB3's ``train()`` has no place for an extra loss, so the host's updates stay SB3's
own and the auxiliary loss trains the critic's encoder with an Adam of its own."""

from __future__ import annotations

import itertools
from collections.abc import Iterable
from typing import Any

import torch as th
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import GymEnv
from torch import nn

from sb3_ef.auxiliary.host import AuxiliaryHostMixin, aux_grad_ratio_due, gradient_norm, gradient_norm_ratio
from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.batch_norm import running_stats_kept
from sb3_ef.common.buffers import SequenceReplayBufferSamples, ShiftedSequenceReplayBuffer
from sb3_ef.common.env_checks import (
    check_box_actions,
    check_stacked_frames,
    n_steps_given_to_buffer,
    policy_observation_space,
    sequence_buffer,
)
from sb3_ef.common.precision import autocast, float32_outputs
from sb3_ef.common.validation import check_algorithm_arguments


class AuxiliaryStepMixin(AuxiliaryHostMixin):
    """Trains an auxiliary loss on the critic encoder of the SB3 algorithm it precedes; other arguments the host's.

    :param shift_pad: random shift (pixels) of the auxiliary step's batch (none with a ShiftedSequenceReplayBuffer).
    :param auxiliary_learning_rate: learning rate (> 0) of the auxiliary step's Adam (``None``: the host's schedule).
    :param check_finite_losses: raise a ``ValueError`` when the auxiliary loss is NaN or infinite, before its step.
    :param precision: ``"fp32"`` or ``"bf16"``: the host's updates and the auxiliary steps (docs/precision.md).
    """

    policy: Any
    critic: Any
    #: The auxiliary module, kept on the algorithm so that the policy stays SB3's own; saved with the model.
    auxiliary_module: AuxiliaryLoss | None = None
    auxiliary_optimizer: th.optim.Optimizer
    replay_buffer_class: type[ReplayBuffer] | None
    replay_buffer_kwargs: dict[str, Any]

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        *,
        shift_pad: int = 4,
        auxiliary_learning_rate: float | None = None,
        check_finite_losses: bool = False,
        precision: str = "fp32",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        check_algorithm_arguments(type(self), locals())
        if env is not None:
            env = maybe_make_env(env, kwargs.get("verbose", 0))
            check_stacked_frames(policy_observation_space(env.observation_space), type(self).__name__)
            check_box_actions(env.action_space, type(self).__name__)
        for name in ("policy_kwargs", "replay_buffer_kwargs"):
            kwargs[name] = dict(kwargs.get(name) or {})
        super().__init__(policy, env, _init_setup_model=False, **kwargs)  # type: ignore[call-arg]
        if shift_pad < 0:
            raise ValueError(f"shift_pad must be >= 0, got {shift_pad}")
        if auxiliary_learning_rate is not None and (
            isinstance(auxiliary_learning_rate, bool)
            or not isinstance(auxiliary_learning_rate, (int, float))
            or not auxiliary_learning_rate > 0
        ):
            raise ValueError(
                "auxiliary_learning_rate must be a positive number (None: the host's learning rate), "
                f"got {auxiliary_learning_rate!r}"
            )
        self.shift_pad = shift_pad
        self.auxiliary_learning_rate = auxiliary_learning_rate
        self.check_finite_losses = check_finite_losses
        self.precision = precision
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """The host's setup with a sequence replay buffer; the auxiliary loss gets an Adam of its own, over its
        module and the critic's features extractor (the encoder it trains besides the critic)."""
        self.replay_buffer_class, self.replay_buffer_kwargs = sequence_buffer(
            self.replay_buffer_class,
            self.replay_buffer_kwargs,
            f"{type(self).__name__} samples the auxiliary loss's batches",
            horizon=max(1, self._auxiliary_horizon()),
            n_steps=self.n_steps,  # type: ignore[attr-defined]
            gamma=self.gamma,  # type: ignore[attr-defined]
        )
        with n_steps_given_to_buffer():
            super()._setup_model()
        auxiliary = self._build_auxiliary()
        if auxiliary is not None:
            self.auxiliary_module = auxiliary.to(self.device)
            self.auxiliary_optimizer = self._auxiliary_adam(auxiliary.parameters())
        if self.precision == "bf16":
            # The actor's Gaussian (SB3's log-probability maths) in float32; channels-last convolutions, 1.07x faster
            # bf16 updates on a CPU (docs/precision.md; float32 keeps its layout, and its bits).
            float32_outputs(self.actor.mu, getattr(self.actor, "log_std", None))  # type: ignore[attr-defined]
            for module in (self.actor, self.critic, self.critic_target, auxiliary):  # type: ignore[attr-defined]
                if module is not None:
                    module.to(memory_format=th.channels_last)  # type: ignore[call-overload]

    def _auxiliary_adam(self, parameters: Iterable[nn.Parameter]) -> th.optim.Optimizer:
        """An Adam over ``parameters`` and the critic's features extractor at the auxiliary learning rate."""
        learning_rate = self.lr_schedule(1) if self.auxiliary_learning_rate is None else self.auxiliary_learning_rate  # type: ignore[attr-defined]
        return th.optim.Adam([*parameters, *self.critic.features_extractor.parameters()], lr=learning_rate)

    @property
    def auxiliary(self) -> AuxiliaryLoss | None:
        """The auxiliary loss module, kept on the algorithm (``auxiliary_module``) so that the policy stays SB3's."""
        return self.auxiliary_module

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of the critic's encoder for uint8 stacked observations (no augmentation)."""
        return self.critic.extract_features(observations.to(self.device), self.critic.features_extractor)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """The host's ``gradient_steps`` updates, unchanged, then as many auxiliary steps."""
        first = self._n_updates + 1
        host_norms: dict[int, th.Tensor] = {}
        hook = self._read_host_gradients(first, host_norms) if self.auxiliary is not None else None
        try:
            with autocast(self.precision, self.device):
                super().train(gradient_steps, batch_size)  # type: ignore[misc]
        finally:
            if hook is not None:
                hook.remove()
        if self.auxiliary is None:
            return
        if self.auxiliary_learning_rate is None:
            self._update_learning_rate(self.auxiliary_optimizer)  # type: ignore[attr-defined]
        self.auxiliary.train(True)
        with autocast(self.precision, self.device):
            updates = [
                self._auxiliary_step(
                    self.replay_buffer.sample(batch_size, env=self._vec_normalize_env),  # type: ignore[attr-defined]
                    host_norms.get(first + step),
                )
                for step in range(gradient_steps)
            ]
        self._record_updates(updates)

    def _read_host_gradients(self, first: int, host_norms: dict[int, th.Tensor]) -> Any:
        """Hook the critic optimiser to keep its encoder-gradient norm; ``None`` when it does not step the encoder."""
        encoder = list(self.critic.features_extractor.parameters())
        held = {id(param) for group in self.critic.optimizer.param_groups for param in group["params"]}
        if not all(id(param) in held for param in encoder):
            return None
        updates = itertools.count(first)

        def read(optimizer: th.optim.Optimizer, args: Any, kwargs: Any) -> None:
            update = next(updates)
            if aux_grad_ratio_due(update):
                host_norms[update] = gradient_norm(encoder)

        return self.critic.optimizer.register_step_pre_hook(read)

    def _auxiliary_step(
        self, batch: SequenceReplayBufferSamples, host_norm: th.Tensor | None = None
    ) -> dict[str, th.Tensor]:
        """One step on the critic's encoder and the auxiliary module; returns the detached logs."""
        assert self.auxiliary is not None
        pad = 0 if isinstance(self.replay_buffer, ShiftedSequenceReplayBuffer) else self.shift_pad  # type: ignore[attr-defined]
        observations, targets = self._augment_observations(batch, pad=pad)
        with running_stats_kept(self.critic.features_extractor):  # the host's batch-norm statistics stay its own
            features = self.encode(observations)
        loss, logs = self.auxiliary(features, targets)
        self._check_finite(**logs)
        self.auxiliary_optimizer.zero_grad()
        loss.backward()
        if host_norm is not None:
            ratio = gradient_norm_ratio(self.critic.features_extractor.parameters(), host_norm)
            logs["aux_grad_ratio"] = self._averaged_aux_grad_ratio(ratio)
        self.auxiliary_optimizer.step()
        self.auxiliary.after_update(self.critic.features_extractor)
        return logs

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()  # type: ignore[misc]
        extra = ["auxiliary_module", "auxiliary_optimizer"] if self.auxiliary is not None else []
        return [*state_dicts, *extra], variables
