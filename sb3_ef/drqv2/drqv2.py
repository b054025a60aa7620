"""DrQ-v2, and DrQv2-EF: DrQ-v2 whose encoder is also trained by Ego-Foresight."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

from sb3_ef.auxiliary.host import AuxiliaryHostMixin, aux_grad_ratio_due, encoder_gradient_ratio
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.compile import CompileOption, compile_kwargs, maybe_compile
from sb3_ef.common.env_checks import (
    check_box_actions,
    check_stacked_frames,
    n_steps_given_to_buffer,
    policy_observation_space,
    sequence_buffer,
)
from sb3_ef.common.exploration import OwnExplorationMixin
from sb3_ef.common.forwarding import base_arguments
from sb3_ef.common.layers import frozen
from sb3_ef.common.precision import autocast
from sb3_ef.common.schedules import StepSchedule, get_step_schedule
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.drqv2.policies import DrQv2Actor, DrQv2Critic, DrQv2EFPolicy, DrQv2Policy
from sb3_ef.ef.host import EFMixin
from sb3_ef.ef.losses import ForesightLoss

SHIFT_PAD = 4
# Keeps sampled actions strictly inside the action bounds, as DrQ-v2's truncated normal does.
_ACTION_EPS = 1e-6


class DrQv2(AuxiliaryHostMixin, OwnExplorationMixin, OffPolicyAlgorithm):
    """DrQ-v2 (Yarats et al., 2021) with SB3's interface; an auxiliary loss joins the critic's (docs/drqv2.md).

    :param policy: the policy (``"CnnPolicy"``) or its class.
    :param env: the environment (uint8 stacked RGB frames, Box actions) or its registered id.
    :param learning_rate: Adam learning rate of every network (encoder, critic, actor, auxiliary), or a schedule.
    :param buffer_size: replay buffer capacity in transitions.
    :param learning_starts: agent steps of uniform random actions before the first update.
    :param batch_size: minibatch size.
    :param tau: soft update coefficient of the critic target.
    :param gamma: discount factor.
    :param train_freq: update every ``train_freq`` agent steps (or ``(n, "step" | "episode")``).
    :param gradient_steps: gradient steps per update (-1: as many as steps collected).
    :param n_steps: n of the n-step return (given to the :class:`SequenceReplayBuffer`).
    :param exploration_std: std of the action noise: a number, ``"linear(initial, final, steps)"`` or a callable.
    :param target_noise_clip: clip of the noise added to the actions of the target and the actor loss.
    :param check_finite_losses: raise a ``ValueError`` naming a NaN or infinite loss before the step (debugging).
    :param compile: ``torch.compile`` the losses: ``False``, ``True``, a mode name or a dict of its arguments.
    :param precision: ``"fp32"`` or ``"bf16"`` (bfloat16 mixed precision of the updates, docs/precision.md).
    :param replay_buffer_class: a :class:`SequenceReplayBuffer` (sub)class; ``None`` picks it.
    :param replay_buffer_kwargs: extra buffer arguments (``n_steps``, ``gamma`` and the horizon are filled in).
    :param stats_window_size: episodes averaged for the rollout logs.
    :param tensorboard_log: tensorboard log folder (``None``: no tensorboard).
    :param policy_kwargs: see :class:`DrQv2Policy`.
    :param verbose: 0 silent, 1 info, 2 debug.
    :param seed: random seed.
    :param device: torch device; ``"auto"`` uses CUDA when available.
    :param _init_setup_model: whether to build the networks at construction.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": DrQv2Policy}
    policy: DrQv2Policy
    actor: DrQv2Actor
    critic: DrQv2Critic
    critic_target: DrQv2Critic
    replay_buffer: SequenceReplayBuffer | None  # _setup_model makes SB3 build one

    def __init__(
        self,
        policy: str | type[DrQv2Policy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 2000,
        batch_size: int = 256,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 2,
        gradient_steps: int = 1,
        n_steps: int = 3,
        exploration_std: float | str | StepSchedule = "linear(1.0,0.1,500000)",
        target_noise_clip: float = 0.3,
        check_finite_losses: bool = False,
        compile: CompileOption = False,
        precision: str = "fp32",
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        check_algorithm_arguments(type(self), locals())
        if env is not None:
            env = maybe_make_env(env, verbose)
            check_stacked_frames(policy_observation_space(env.observation_space), "DrQ-v2")
            check_box_actions(env.action_space, "DrQ-v2")
        super().__init__(
            **base_arguments(
                OffPolicyAlgorithm,
                locals(),
                replay_buffer_kwargs=dict(replay_buffer_kwargs or {}),
                policy_kwargs=dict(policy_kwargs or {}),
                sde_support=False,
                supported_action_spaces=(spaces.Box,),
                support_multi_env=True,
            )
        )
        self.exploration_std = exploration_std
        self.target_noise_clip = target_noise_clip
        self.check_finite_losses = check_finite_losses
        compile_kwargs(compile)
        self.compile = compile
        self.precision = precision

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """SB3's setup with a sequence replay buffer (n-step returns); the auxiliary loss joins the critic's Adam."""
        self.replay_buffer_class, self.replay_buffer_kwargs = sequence_buffer(
            self.replay_buffer_class,
            self.replay_buffer_kwargs,
            "DrQ-v2 samples n-step discounts (and DrQv2-EF its windows)",
            horizon=max(1, self._auxiliary_horizon()),
            n_steps=self.n_steps,
            gamma=self.gamma,
        )
        with n_steps_given_to_buffer():
            super()._setup_model()
        self._create_aliases()
        auxiliary = self._build_auxiliary()
        if auxiliary is not None:
            self.policy.auxiliary = auxiliary.to(self.device)
            # The auxiliary loss is added to the critic's, so its modules step with the encoder and the critic:
            # one more parameter group in the critic's Adam, at the same learning rate (the EF authors' setting).
            self.critic.optimizer.add_param_group({"params": list(auxiliary.parameters())})
        self.exploration_schedule = get_step_schedule(self.exploration_std)
        self._critic_and_auxiliary_loss = maybe_compile(self._critic_and_auxiliary_loss, self.compile)  # type: ignore[method-assign]
        self._actor_loss = maybe_compile(self._actor_loss, self.compile)  # type: ignore[method-assign]

    def _create_aliases(self) -> None:
        self.actor = self.policy.actor
        self.critic = self.policy.critic
        self.critic_target = self.policy.critic_target

    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """``gradient_steps`` updates on replay batches, at the learning rate of the schedule."""
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        updates = []
        for _ in range(gradient_steps):
            self._n_updates += 1
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            with autocast(self.precision, self.device):
                updates.append(self._update(batch))
        self._record_updates(updates)
        self.logger.record("train/exploration_std", self.exploration_schedule(self.num_timesteps))

    def _update(self, batch: SequenceReplayBufferSamples) -> dict[str, th.Tensor]:
        """One DrQ-v2 update (``DrQV2Agent.update``), plus the auxiliary loss in the critic's step.

        1. Shift the observations at t and t+n by up to 4 pixels (the auxiliary loss shifts its targets with t).
        2. Critic: the encoder is trained by the critic only (and the auxiliary loss): ``h = encoder(obs)``, and
           ``h' = encoder(next_obs)`` without gradient (no target encoder). Clipped double Q against
           ``r_n + (1 - done) * gamma^n * min(Q1', Q2')(h', a')``, ``a'`` the actor's mean plus clipped noise of
           the scheduled std; the n-step sum, discount and terminal flag come from the buffer.
        3. One step of the critic's Adam (encoder, critic and the auxiliary module) on ``critic + auxiliary``.
        4. Actor on detached features: ``-min(Q1, Q2)(h, a)``, the critic frozen; its own Adam.
        5. Polyak update of the critic target (``tau``); the auxiliary's ``after_update``.
        The std is a tensor so that its schedule does not recompile a compiled loss.
        """
        compiled = self.compile is not False
        if compiled:
            th.compiler.cudagraph_mark_step_begin()
        std = th.tensor(self.exploration_schedule(self.num_timesteps), device=self.device)
        observations, next_observations, targets = self._augment(batch)
        critic_loss, auxiliary_loss, features, logs = self._critic_and_auxiliary_loss(
            observations, next_observations, targets, batch, std
        )
        if auxiliary_loss is not None and not compiled and aux_grad_ratio_due(self._n_updates):
            ratio = encoder_gradient_ratio(auxiliary_loss, critic_loss, self.policy.encoder.parameters())
            logs["aux_grad_ratio"] = self._averaged_aux_grad_ratio(ratio)
        self._check_finite(**logs)
        self.critic.optimizer.zero_grad()
        (critic_loss if auxiliary_loss is None else critic_loss + auxiliary_loss).backward()
        self.critic.optimizer.step()

        with frozen(self.critic):
            actor_loss = self._actor_loss(features.detach(), std)
        self._check_finite(actor_loss=actor_loss)
        self.actor.optimizer.zero_grad()
        actor_loss.backward()
        self.actor.optimizer.step()

        polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
        if self.auxiliary is not None:
            self.auxiliary.after_update(self.policy.encoder)
        logs["actor_loss"] = actor_loss.detach()
        # CUDA graph outputs are overwritten by the next replay: keep copies.
        return {name: value.clone() for name, value in logs.items()} if compiled else logs

    def _augment(self, batch: SequenceReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, Any]:
        """Shift the next observations, then the observations: by the auxiliary loss, with its targets, if any."""
        (next_observations,) = random_shift(batch.next_observations, pad=SHIFT_PAD)
        observations, targets = self._augment_observations(batch, pad=SHIFT_PAD)
        return observations, next_observations, targets

    def _critic_and_auxiliary_loss(
        self,
        observations: th.Tensor,
        next_observations: th.Tensor,
        targets: Any,
        batch: SequenceReplayBufferSamples,
        std: th.Tensor,
    ) -> tuple[th.Tensor, th.Tensor | None, th.Tensor, dict[str, th.Tensor]]:
        """Critic loss, weighted auxiliary loss (or ``None``), the encoder features and the scalars to log."""
        features = self.policy.encoder(observations)
        with th.no_grad():
            next_features = self.policy.encoder(next_observations)
        critic_loss, q_mean = self._critic_loss(features, batch, next_features, std)
        logs = {"critic_loss": critic_loss.detach(), "q_values": q_mean}
        auxiliary_loss = None
        if self.auxiliary is not None:
            auxiliary_loss, auxiliary_logs = self.auxiliary(features, targets)
            logs.update(auxiliary_logs)
        return critic_loss, auxiliary_loss, features, logs

    def _noisy_actions(self, features: th.Tensor, std: float | th.Tensor) -> th.Tensor:
        """Actor mean plus clipped noise, clamped straight-through (DrQ-v2's truncated normal sample)."""
        mean = self.actor(features).float()  # the noise and the clamp to 1 - 1e-6 in float32 (bf16 rounds to 1)
        noise = (th.randn_like(mean) * std).clamp(-self.target_noise_clip, self.target_noise_clip)
        actions = mean + noise
        clamped = actions.clamp(-1.0 + _ACTION_EPS, 1.0 - _ACTION_EPS)
        return actions - actions.detach() + clamped.detach()

    def _critic_loss(
        self, features: th.Tensor, batch: SequenceReplayBufferSamples, next_features: th.Tensor, std: float | th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """Clipped double-Q n-step TD loss and the detached mean Q."""
        with th.no_grad():
            next_actions = self._noisy_actions(next_features, std)
            next_q = th.cat(self.critic_target(next_features, next_actions), dim=1).min(dim=1, keepdim=True).values
            target_q = batch.rewards + (1.0 - batch.dones) * batch.discounts * next_q
        # Q in float32 for the loss and its reductions (a no-op in float32; under bf16 autocast, the heads' output).
        current_q = [q.float() for q in self.critic(features, batch.actions)]
        loss = sum(F.mse_loss(q, target_q) for q in current_q)
        assert isinstance(loss, th.Tensor)
        return loss, th.cat(current_q, dim=1).mean().detach()

    def _actor_loss(self, features: th.Tensor, std: float | th.Tensor) -> th.Tensor:
        """Minus the smaller Q of the noisy actor actions (the critic is frozen by the caller)."""
        q_values = th.cat(self.critic(features, self._noisy_actions(features, std)), dim=1).float()
        return -q_values.min(dim=1).values.mean()

    def _exploration_action(self, n_envs: int) -> np.ndarray:
        assert self._last_obs is not None, "self._last_obs was not set"
        mean, _ = self.predict(self._last_obs, deterministic=True)
        std = self.exploration_schedule(self.num_timesteps)
        noisy = self.policy.scale_action(mean) + std * np.random.standard_normal(mean.shape)
        return np.clip(noisy, -1.0 + _ACTION_EPS, 1.0 - _ACTION_EPS).astype(np.float32)

    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "actor",
            "critic",
            "critic_target",
            "exploration_schedule",
            "_critic_and_auxiliary_loss",
            "_actor_loss",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "actor.optimizer", "critic.optimizer"], []


class DrQv2EF(EFMixin, DrQv2):
    """:class:`DrQv2` whose encoder is also trained by Ego-Foresight (docs/ef.md); other arguments as :class:`DrQv2`.

    :param beta: weight of the Ego-Foresight loss (to train without EF, use :class:`DrQv2`).
    :param ef_horizon: Ego-Foresight prediction horizon H (the rollout length k is drawn in [1, H]).
    :param babbling_steps: agent steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` (random +-1) or ``"clamped_uniform"`` (the authors' code).
    :param babbling_in_eval: ``predict`` also babbles during the babbling steps (the EF authors' Meta-World protocol).
    :param policy_kwargs: see :class:`DrQv2EFPolicy`.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": DrQv2EFPolicy}
    policy: DrQv2EFPolicy

    def __init__(
        self,
        policy: str | type[DrQv2EFPolicy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 1e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int = 2000,
        batch_size: int = 256,
        tau: float = 0.01,
        gamma: float = 0.99,
        train_freq: int | tuple[int, str] = 2,
        gradient_steps: int = 1,
        n_steps: int = 3,
        exploration_std: float | str | StepSchedule = "linear(1.0,0.1,500000)",
        target_noise_clip: float = 0.3,
        beta: float = 1.0,
        ef_horizon: int = 10,
        babbling_steps: int = 12_500,
        babbling_mode: str = "sign",
        babbling_in_eval: bool = False,
        check_finite_losses: bool = False,
        compile: CompileOption = False,
        precision: str = "fp32",
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: th.device | str = "auto",
        _init_setup_model: bool = True,
    ):
        super().__init__(**base_arguments(DrQv2, locals(), _init_setup_model=False))
        ef_kwargs = self.policy_kwargs.get("ef_kwargs")
        self._init_ef(beta, ef_horizon, babbling_steps, babbling_mode, babbling_in_eval, ef_kwargs)
        if _init_setup_model:
            self._setup_model()

    def _build_auxiliary(self) -> ForesightLoss:
        """EF on the encoder the critic trains, sized by the EF policy (the encoder takes the uint8 frames)."""
        policy = self._ef_policy()
        encoder = policy.encoder
        return self._foresight_loss(
            encoder, encoder.features_dim, policy.agent_dim, policy.ef_kwargs, policy.channels_last
        )
