"""DrQv2-EF: DrQ-v2 whose encoder is also trained by Ego-Foresight; and DrQ-v2 itself (EF off)."""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

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

from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.ef_host import (
    EFHostMixin,
    check_box_actions,
    check_ef_arguments,
    check_horizon_fits_episodes,
    check_sequence_buffer,
    check_stacked_frames,
    episode_steps,
)
from sb3_ef.common.schedules import StepSchedule, get_step_schedule
from sb3_ef.drqv2.policies import DrQv2Actor, DrQv2Critic, DrQv2Policy

SHIFT_PAD = 4
# Keeps sampled actions strictly inside the action bounds, as DrQ-v2's truncated normal does.
_ACTION_EPS = 1e-6


class EFWindow(NamedTuple):
    """What one update needs from the EF window: rollout lengths, their (shifted) target frames and validity."""

    steps: th.Tensor
    target: th.Tensor
    valid: th.Tensor


class DrQv2EF(EFHostMixin, OffPolicyAlgorithm):
    """DrQv2-EF (Ego-Foresight on DrQ-v2): the encoder is trained by ``critic_loss + beta * ef_loss``.

    DrQ-v2: random-shift augmentation, a shared conv encoder trained by the critic only, a deterministic actor on
    detached features with a scheduled exploration std, clipped double Q with n-step returns and a critic target
    (no target encoder). Ego-Foresight adds a pooled projection of the encoder output, a rollout of the agent part
    of the features under the next actions and a decoder that predicts the frame ``k`` steps ahead; motor babbling
    (random +-1 actions) fills the first ``babbling_steps`` agent steps.

    Paper: Nunes et al., "Ego-Foresight: Self-supervised Learning of Agent-Aware Representations for Improved RL"
    (ICLR 2026); DrQ-v2: Yarats et al., "Mastering Visual Continuous Control" (2021).

    :param policy: the policy (``"CnnPolicy"``) or its class.
    :param env: the environment (uint8 stacked RGB frames, channels-first; Box actions) or its registered id.
    :param learning_rate: Adam learning rate of every network (encoder, critic, actor, EF), or a schedule.
    :param buffer_size: replay buffer capacity in transitions.
    :param learning_starts: agent steps of uniform random actions before the first update.
    :param batch_size: minibatch size.
    :param tau: soft update coefficient of the critic target.
    :param gamma: discount factor.
    :param train_freq: update every ``train_freq`` agent steps (or ``(n, "step" | "episode")``).
    :param gradient_steps: gradient steps per update (-1: as many as steps collected).
    :param n_steps: n of the n-step return (given to the :class:`SequenceReplayBuffer`).
    :param exploration_std: std of the rollout and target-policy noise, as a function of agent steps: a number, a
        ``"linear(initial, final, duration)"`` string or a callable.
    :param target_noise_clip: clip of the noise added to the actions of the target and the actor loss.
    :param beta: weight of the Ego-Foresight loss (to switch EF off, use :class:`DrQv2`).
    :param ef_horizon: Ego-Foresight prediction horizon H (the rollout length k is drawn in [1, H]).
    :param babbling_steps: agent steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` (random +-1) or ``"clamped_uniform"`` (the authors' code).
    :param replay_buffer_class: a :class:`SequenceReplayBuffer` (sub)class; ``None`` picks it.
    :param replay_buffer_kwargs: extra buffer arguments (``n_steps``, ``gamma`` and the horizon are filled in).
    :param stats_window_size: episodes averaged for the rollout logs.
    :param tensorboard_log: tensorboard log folder (``None``: no tensorboard).
    :param policy_kwargs: policy arguments, see :class:`DrQv2Policy` (``agent_dim``, ``ef_kwargs``, ``net_arch``,
        ``trunk_dim``, ``features_dim``, ...).
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
        beta: float = 1.0,
        ef_horizon: int = 10,
        babbling_steps: int = 12_500,
        babbling_mode: str = "sign",
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
        if self.uses_ef:
            check_ef_arguments(beta, ef_horizon, babbling_steps, plain_variant="DrQv2")
            check_sequence_buffer(replay_buffer_class, "DrQv2EF samples Ego-Foresight windows")
        if env is not None:
            env = maybe_make_env(env, verbose)
            check_stacked_frames(env.observation_space, "DrQ-v2")
            check_box_actions(env.action_space, "DrQ-v2")
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau,
            gamma,
            train_freq,
            gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            n_steps=n_steps,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Box,),
            support_multi_env=True,
        )
        self.exploration_std = exploration_std
        self.target_noise_clip = target_noise_clip
        self.beta = beta if self.uses_ef else None
        self.ef_horizon = ef_horizon if self.uses_ef else None
        self.babbling_steps = babbling_steps
        self.babbling_mode = babbling_mode
        self.policy_kwargs["ef_horizon"] = self.ef_horizon

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """Build the schedules, the sequence replay buffer (it computes the n-step returns itself, so SB3's
        n-step buffer selection is not used) and the policy. Runs after the saved attributes are restored on load,
        so the horizon is checked against the env with the model's own ``ef_horizon``."""
        if self.env is not None:
            check_horizon_fits_episodes(self.ef_horizon, episode_steps(self.env))
        self._setup_lr_schedule()
        self.exploration_schedule = get_step_schedule(self.exploration_std)
        self.set_random_seed(self.seed)
        if self.replay_buffer_class is None:
            self.replay_buffer_class = SequenceReplayBuffer
        if self.replay_buffer is None:
            buffer_kwargs = self.replay_buffer_kwargs.copy()
            if issubclass(self.replay_buffer_class, SequenceReplayBuffer):
                buffer_kwargs.setdefault("n_steps", self.n_steps)
                buffer_kwargs.setdefault("gamma", self.gamma)
                # Plain DrQ-v2 reads no EF window: the shortest one keeps sampling cheap.
                buffer_kwargs["horizon"] = self.ef_horizon if self.ef_horizon is not None else 1
            self.replay_buffer = self.replay_buffer_class(
                self.buffer_size,
                self.observation_space,
                self.action_space,
                device=self.device,
                n_envs=self.n_envs,
                optimize_memory_usage=self.optimize_memory_usage,
                **buffer_kwargs,
            )
        self.policy = self.policy_class(
            self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs
        )
        self.policy = self.policy.to(self.device)
        self._convert_train_freq()
        self._create_aliases()

    def _create_aliases(self) -> None:
        self.actor = self.policy.actor
        self.critic = self.policy.critic
        self.critic_target = self.policy.critic_target

    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """DrQ-v2's update, plus the EF loss on the same encoder output:
        augment -> encode -> critic (+ beta * EF) step on encoder, critic, EF -> actor step -> critic target."""
        self.policy.set_training_mode(True)
        self._update_learning_rate([self.actor.optimizer, self.critic.optimizer])
        std = self.exploration_schedule(self.num_timesteps)
        critic_losses, actor_losses, ef_losses, q_values = [], [], [], []

        for _ in range(gradient_steps):
            self._n_updates += 1
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            observations, next_observations, window = self._augment(batch)

            features = self.policy.encoder(observations)
            with th.no_grad():
                next_features = self.policy.encoder(next_observations)

            critic_loss, q_mean = self._critic_loss(features, batch, next_features, std)
            loss = critic_loss
            if window is not None:
                ef_loss = self._ef_loss(features, batch.future_actions, window)
                loss = loss + self.beta * ef_loss
                ef_losses.append(ef_loss.item())
            self.critic.optimizer.zero_grad()
            loss.backward()
            self.critic.optimizer.step()

            actor_loss = self._actor_loss(features.detach(), std)
            self.actor.optimizer.zero_grad()
            actor_loss.backward()
            self.actor.optimizer.step()

            polyak_update(self.critic.parameters(), self.critic_target.parameters(), self.tau)
            critic_losses.append(critic_loss.item())
            actor_losses.append(actor_loss.item())
            q_values.append(q_mean)

        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/critic_loss", np.mean(critic_losses))
        self.logger.record("train/actor_loss", np.mean(actor_losses))
        self.logger.record("train/q_values", np.mean(q_values))
        self.logger.record("train/exploration_std", std)
        if ef_losses:
            self.logger.record("train/ef_loss", np.mean(ef_losses))

    def _augment(self, batch: SequenceReplayBufferSamples) -> tuple[th.Tensor, th.Tensor, EFWindow | None]:
        """Random-shift the observations and next observations; with EF, draw the rollout length k and shift the
        frame k steps ahead together with the observation it is predicted from."""
        (next_observations,) = random_shift(batch.next_observations, pad=SHIFT_PAD)
        if self.ef is None:
            (observations,) = random_shift(batch.observations, pad=SHIFT_PAD)
            return observations, next_observations, None
        steps = self.ef.draw_steps(batch.future_mask)
        rows = th.arange(steps.shape[0], device=steps.device)
        observations, target = random_shift(batch.observations, batch.future_frames[rows, steps - 1], pad=SHIFT_PAD)
        return observations, next_observations, EFWindow(steps, target, batch.future_mask[rows, steps - 1])

    def _noisy_actions(self, features: th.Tensor, std: float) -> th.Tensor:
        """Actor mean plus clipped Gaussian noise, clamped to the action bounds with a straight-through gradient
        (DrQ-v2's truncated normal sample)."""
        mean = self.actor(features)
        noise = (th.randn_like(mean) * std).clamp(-self.target_noise_clip, self.target_noise_clip)
        actions = mean + noise
        clamped = actions.clamp(-1.0 + _ACTION_EPS, 1.0 - _ACTION_EPS)
        return actions - actions.detach() + clamped.detach()

    def _critic_loss(
        self, features: th.Tensor, batch: SequenceReplayBufferSamples, next_features: th.Tensor, std: float
    ) -> tuple[th.Tensor, float]:
        """Clipped double-Q n-step TD loss against the critic target; returns the loss and the mean Q value."""
        with th.no_grad():
            next_actions = self._noisy_actions(next_features, std)
            next_q = th.cat(self.critic_target(next_features, next_actions), dim=1).min(dim=1, keepdim=True).values
            target_q = batch.rewards + (1.0 - batch.dones) * batch.discounts * next_q
        current_q = self.critic(features, batch.actions)
        loss = sum(F.mse_loss(q, target_q) for q in current_q)
        assert isinstance(loss, th.Tensor)
        return loss, th.cat(current_q, dim=1).mean().item()

    def _ef_loss(self, features: th.Tensor, future_actions: th.Tensor, window: EFWindow) -> th.Tensor:
        """Ego-Foresight loss: roll the agent features k actions ahead and reconstruct frame t+k."""
        assert self.ef is not None
        return self.ef.loss(features, future_actions, window.steps, window.target, window.valid)

    def _actor_loss(self, features: th.Tensor, std: float) -> th.Tensor:
        """Deterministic policy gradient through the minimum of the Q heads, on detached features. The critic's
        weights are frozen meanwhile: only the actor learns from this loss (and no weight gradients are computed
        for the critic)."""
        self.critic.requires_grad_(False)
        try:
            q_values = th.cat(self.critic(features, self._noisy_actions(features, std)), dim=1)
        finally:
            self.critic.requires_grad_(True)
        return -q_values.min(dim=1).values.mean()

    def _exploration_action(self, n_envs: int) -> np.ndarray:
        """The actor mean plus Gaussian noise with the scheduled std, kept inside the action bounds."""
        assert self._last_obs is not None, "self._last_obs was not set"
        mean, _ = self.predict(self._last_obs, deterministic=True)
        std = self.exploration_schedule(self.num_timesteps)
        noisy = self.policy.scale_action(mean) + std * np.random.standard_normal(mean.shape)
        return np.clip(noisy, -1.0 + _ACTION_EPS, 1.0 - _ACTION_EPS).astype(np.float32)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "actor", "critic", "critic_target", "exploration_schedule"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "actor.optimizer", "critic.optimizer"], []


class DrQv2(DrQv2EF):
    """DrQ-v2 (Yarats et al., 2021): :class:`DrQv2EF` without Ego-Foresight, with the reference's unprojected
    encoder output (32 * 35 * 35 = 39200 features at 84x84) and no motor babbling.

    Same arguments as :class:`DrQv2EF` minus the EF ones (``beta``, ``ef_horizon``, ``babbling_steps``,
    ``babbling_mode``); ``policy_kwargs["features_dim"]`` defaults to ``None`` (no projection).
    """

    uses_ef: ClassVar[bool] = False

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
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            n_steps=n_steps,
            exploration_std=exploration_std,
            target_noise_clip=target_noise_clip,
            babbling_steps=0,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs={"features_dim": None, **(policy_kwargs or {})},
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=_init_setup_model,
        )
