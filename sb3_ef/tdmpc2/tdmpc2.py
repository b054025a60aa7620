"""TD-MPC2 (Hansen et al., ICLR 2024) for pixels: a standalone model-based algorithm with SB3's interface."""

from __future__ import annotations

from functools import partial
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.noise import ActionNoise
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_ef.auxiliary.host import AuxiliaryHostMixin, aux_grad_ratio_due, encoder_gradient_ratio
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.compile import CompileOption, compile_kwargs, maybe_compile
from sb3_ef.common.env_checks import check_box_actions, policy_observation_space, sequence_buffer
from sb3_ef.common.exploration import OwnExplorationMixin
from sb3_ef.common.forwarding import base_arguments
from sb3_ef.common.layers import frozen
from sb3_ef.common.policy_arguments import policy_built_with
from sb3_ef.common.precision import autocast
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.tdmpc2.arguments import check_arguments, known_episode_steps
from sb3_ef.tdmpc2.gradients import clipped_world_model_gradients
from sb3_ef.tdmpc2.math import discount_from_episode_length, seed_steps_from_episode_length, update_q_scale
from sb3_ef.tdmpc2.policies import TDMPC2Policy, check_pixel_space
from sb3_ef.tdmpc2.sequence import SHIFT_PAD, Sequence, masked_mean, training_sequence
from sb3_ef.tdmpc2.world_model import WorldModel


class TDMPC2(AuxiliaryHostMixin, OwnExplorationMixin, OffPolicyAlgorithm):
    """TD-MPC2 (Hansen et al., ICLR 2024) for pixels with SB3's interface and an auxiliary loss hook (docs/tdmpc2.md).

    :param policy: ``"CnnPolicy"`` or a :class:`TDMPC2Policy` (sub)class.
    :param env: the environment (uint8 stacked 64x64 RGB frames, Box actions) or its id.
    :param learning_rate: Adam learning rate (the encoder uses ``policy_kwargs["encoder_lr_scale"]`` times it).
    :param buffer_size: replay buffer capacity (frames).
    :param learning_starts: seed steps S (random actions at 0..S); ``None``: ``max(1000, 5 x episode length)``.
    :param batch_size: minibatch size.
    :param tau: Polyak coefficient of the target Q-ensemble and of the running Q scale.
    :param gamma: discount; ``None`` derives it from the episode length (TD-MPC2's heuristic).
    :param horizon: world-model and planning horizon.
    :param consistency_coef: weight of the latent consistency loss.
    :param reward_coef: weight of the reward cross-entropy.
    :param value_coef: weight of the value cross-entropy.
    :param entropy_coef: weight of the policy prior's (action-dim scaled) entropy bonus.
    :param rho: per-step decay of the loss weights over the horizon.
    :param max_grad_norm: gradient clipping norm (world model, auxiliary loss and policy prior each clipped apart).
    :param seed_burst: run as many updates as seed steps when they end (TD-MPC2); ``False``: one update per step.
    :param check_finite_losses: raise a ``ValueError`` naming a NaN or infinite loss before the step (debugging).
    :param compile: ``torch.compile`` the losses: ``False``, ``True``, a mode name or a dict of its arguments.
    :param precision: ``"fp32"`` or ``"bf16"`` (bfloat16 mixed precision of the updates and the planner,
        docs/precision.md).
    :param replay_buffer_class: a :class:`SequenceReplayBuffer` (sub)class; ``None`` picks it.
    :param replay_buffer_kwargs: extra buffer arguments (``n_steps`` and the window horizon are filled in).
    :param stats_window_size: episodes averaged for the rollout logs.
    :param tensorboard_log: tensorboard log folder (``None``: no tensorboard).
    :param policy_kwargs: see :class:`TDMPC2Policy`.
    :param verbose: 0 silent, 1 info, 2 debug.
    :param seed: random seed.
    :param device: torch device; ``"auto"`` uses CUDA when available.
    :param _init_setup_model: whether to build the networks at construction.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": TDMPC2Policy}
    policy: TDMPC2Policy
    replay_buffer: SequenceReplayBuffer | None  # _setup_model makes SB3 build one

    def __init__(
        self,
        policy: str | type[TDMPC2Policy],
        env: GymEnv | str,
        learning_rate: float | Schedule = 3e-4,
        buffer_size: int = 1_000_000,
        learning_starts: int | None = None,
        batch_size: int = 256,
        tau: float = 0.01,
        gamma: float | None = None,
        horizon: int = 3,
        consistency_coef: float = 20.0,
        reward_coef: float = 0.1,
        value_coef: float = 0.1,
        entropy_coef: float = 1e-4,
        rho: float = 0.5,
        max_grad_norm: float = 20.0,
        seed_burst: bool = True,
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
        check_arguments(horizon, policy_kwargs)
        if env is not None:
            env = maybe_make_env(env, verbose)
            check_pixel_space(policy_observation_space(env.observation_space))
            check_box_actions(env.action_space, "TD-MPC2")
        super().__init__(
            **base_arguments(
                OffPolicyAlgorithm,
                locals(),
                train_freq=1,
                gradient_steps=-1,
                replay_buffer_kwargs=dict(replay_buffer_kwargs or {}),
                policy_kwargs=dict(policy_kwargs or {}),
                sde_support=False,
                supported_action_spaces=(spaces.Box,),
                support_multi_env=True,
            )
        )
        self.horizon = horizon
        self.consistency_coef = consistency_coef
        self.reward_coef = reward_coef
        self.value_coef = value_coef
        self.entropy_coef = entropy_coef
        self.rho = rho
        self.max_grad_norm = max_grad_norm
        self.seed_burst = seed_burst
        self.check_finite_losses = check_finite_losses
        compile_kwargs(compile)
        self.compile = compile
        self.precision = precision
        self._rollout_plan: th.Tensor | None = None

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """SB3's setup with a sequence replay buffer, the planner's horizon and discount; the auxiliary loss joins the
        world model's Adam; compiled losses."""
        self._derive_from_episode_length()
        self.replay_buffer_class, self.replay_buffer_kwargs = sequence_buffer(
            self.replay_buffer_class,
            self.replay_buffer_kwargs,
            "TD-MPC2 trains on consecutive steps",
            horizon=self.window,
            n_steps=1,
        )
        with policy_built_with(self, horizon=self.horizon, gamma=self.gamma, precision=self.precision):
            super()._setup_model()
        auxiliary = self._build_auxiliary()
        if auxiliary is not None:
            self.policy.auxiliary = auxiliary.to(self.device)
            # The auxiliary loss is added to the world model's: its modules step in the world model's Adam, in a
            # group of their own (named, so that their gradient is clipped apart: tdmpc2/gradients.py).
            self.policy.optimizer.add_param_group({"name": "auxiliary", "params": list(auxiliary.parameters())})
        self._world_model_losses = maybe_compile(self._world_model_losses, self.compile)  # type: ignore[method-assign]
        self._policy_loss = maybe_compile(self._policy_loss, self.compile)  # type: ignore[method-assign]

    def _derive_from_episode_length(self) -> None:
        """TD-MPC2's discount and seed steps for ``None`` (here, not in ``__init__``: ``load`` keeps saved values)."""
        if self.gamma is None:
            self.gamma = discount_from_episode_length(known_episode_steps(self.env, "gamma"))
        if self.learning_starts is None:
            self.learning_starts = seed_steps_from_episode_length(known_episode_steps(self.env, "learning_starts"))

    @property
    def window(self) -> int:
        """Steps of the replay window: the longer of the model's and the auxiliary loss's horizons."""
        return max(self.horizon, self._auxiliary_horizon())

    @property
    def world_model(self) -> WorldModel:
        return self.policy.world_model

    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """``gradient_steps`` updates (the first round: ``learning_starts``, TD-MPC2's pretraining on the seed data)
        at the learning rate of the schedule, the encoder's group at its ``lr_scale``."""
        self.policy.set_training_mode(True)
        learning_rate = self.lr_schedule(self._current_progress_remaining)
        self.logger.record("train/learning_rate", learning_rate)
        for optimizer in (self.policy.optimizer, self.policy.pi_optimizer):
            for group in optimizer.param_groups:
                group["lr"] = learning_rate * group.get("lr_scale", 1.0)
        if self.seed_burst and self._n_updates == 0:
            gradient_steps = max(gradient_steps, self.learning_starts)
        updates = []
        for _ in range(gradient_steps):
            self._n_updates += 1
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            with autocast(self.precision, self.device):
                updates.append(self._update(batch))
        self._record_updates(updates)

    def _update(self, batch: SequenceReplayBufferSamples) -> dict[str, th.Tensor]:
        """One TD-MPC2 update (tdmpc2's ``_update``), with the auxiliary loss on the first latent.

        1. The window, time-major, every observation shifted by up to 3 pixels (the one at t by the auxiliary loss,
           with its targets); TD targets ``r + gamma * min`` of two random target Q heads at the prior's action on
           the encodings of t+1..t+H, without gradient.
        2. The latent rolled forward from ``z_t = encode(obs_t)`` with the actions: consistency (squared error to
           the encodings), reward and value (two-hot cross-entropies), each weighted ``rho^t`` over the horizon.
        3. The auxiliary loss (``beta`` times EF's) on ``z_t``.
        4. One step of the world model's Adam (encoder at ``encoder_lr_scale``, auxiliary modules in their group):
           ``20 consistency + 0.1 reward + 0.1 value`` clipped to ``max_grad_norm``, the auxiliary's gradient
           clipped to it on its own and added (docs/tdmpc2.md).
        5. The policy prior on the detached latents, the Q heads frozen: its own Adam and clip.
        6. Soft update of the target Q heads; the auxiliary's ``after_update``.
        """
        compiled = self.compile is not False
        if compiled:
            th.compiler.cudagraph_mark_step_begin()
        losses, auxiliary, latents, valid = self.losses(batch)
        host_loss = (
            self.consistency_coef * losses["consistency_loss"]
            + self.reward_coef * losses["reward_loss"]
            + self.value_coef * losses["value_loss"]
        )
        auxiliary_loss, auxiliary_logs = auxiliary if auxiliary is not None else (None, {})
        self._check_finite(**losses, **({} if auxiliary_loss is None else {"auxiliary_loss": auxiliary_loss}))
        logs = {**{key: value.detach() for key, value in losses.items()}, **auxiliary_logs}
        logs["total_loss"] = (host_loss if auxiliary_loss is None else host_loss + auxiliary_loss).detach()
        if auxiliary_loss is not None and not compiled and aux_grad_ratio_due(self._n_updates):
            ratio = encoder_gradient_ratio(auxiliary_loss, host_loss, self.world_model.encoder.parameters())
            logs["aux_grad_ratio"] = self._averaged_aux_grad_ratio(ratio)
        self.policy.optimizer.zero_grad()
        logs.update(clipped_world_model_gradients(self.policy.optimizer, host_loss, auxiliary_loss, self.max_grad_norm))
        self.policy.optimizer.step()

        logs["pi_loss"] = self._policy_step(latents.detach(), valid)
        self.world_model.soft_update_target_q(self.tau)
        if self.auxiliary is not None:
            self.auxiliary.after_update(self.world_model.encoder)
        logs["q_scale"] = self.policy.q_scale.clone()
        # CUDA graph outputs are overwritten by the next replay: keep copies.
        return {name: value.clone() for name, value in logs.items()} if compiled else logs

    def _policy_step(self, latents: th.Tensor, valid: th.Tensor) -> th.Tensor:
        """The policy prior's step on :meth:`_policy_loss`, the Q-ensemble frozen; returns the detached loss."""
        with frozen(self.world_model.q_heads):
            pi_loss = self._policy_loss(latents, valid)
        self._check_finite(pi_loss=pi_loss)
        self.policy.pi_optimizer.zero_grad()
        pi_loss.backward()
        th.nn.utils.clip_grad_norm_(self.world_model.pi_head.parameters(), self.max_grad_norm)
        self.policy.pi_optimizer.step()
        return pi_loss.detach()

    def losses(self, batch: SequenceReplayBufferSamples) -> tuple[dict[str, th.Tensor], Any, th.Tensor, th.Tensor]:
        """The unweighted world-model losses, the auxiliary's ``(weighted loss, logs)`` (``None`` without one), the
        latents ``(H+1, B, L)`` and their validity."""
        augment_first = partial(self._augment_observations, pad=SHIFT_PAD)
        return self._world_model_losses(training_sequence(batch, self.horizon, augment_first))

    def _world_model_losses(self, sequence: Sequence) -> tuple[dict[str, th.Tensor], Any, th.Tensor, th.Tensor]:
        next_latents, td_targets = self._td_targets(sequence)
        first_latent = self.world_model.encode(sequence.first)
        rollout, consistency_loss = self._rollout_and_consistency_loss(first_latent, sequence, next_latents)
        losses = {
            "consistency_loss": consistency_loss,
            "reward_loss": self._reward_loss(rollout, sequence),
            "value_loss": self._value_loss(rollout, sequence, td_targets),
        }
        auxiliary = None if self.auxiliary is None else self.auxiliary(first_latent, sequence.auxiliary_targets)
        first_valid = th.ones_like(sequence.valid[:1])
        return losses, auxiliary, rollout, th.cat([first_valid, sequence.valid])

    def _td_targets(self, sequence: Sequence) -> tuple[th.Tensor, th.Tensor]:
        """Encodings ``(H, B, L)`` of t+1..t+H and TD targets ``(H, B)`` from the min of two random target Q heads."""
        model = self.world_model
        with th.no_grad():
            next_latents = model.encode(sequence.following.flatten(0, 1)).unflatten(0, sequence.following.shape[:2])
            next_actions = model.pi(next_latents).action
            next_q = model.q_value(next_latents, next_actions, reduce="min", target=True)
        return next_latents, sequence.rewards + self.gamma * next_q

    def _rollout_and_consistency_loss(
        self, first_latent: th.Tensor, sequence: Sequence, next_latents: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor]:
        """The latents ``(H+1, B, L)`` rolled forward from t, and their squared error against the real encodings."""
        z = first_latent
        latents, errors = [z], []
        for t in range(self.horizon):
            z = self.world_model.next(z, sequence.actions[t])
            errors.append((z - next_latents[t]).pow(2).mean(-1))
            latents.append(z)
        return th.stack(latents), self._over_horizon(th.stack(errors), sequence.valid)

    def _reward_loss(self, rollout: th.Tensor, sequence: Sequence) -> th.Tensor:
        logits = self.world_model.reward(rollout[:-1], sequence.actions)
        return self._over_horizon(self.world_model.two_hot.cross_entropy(logits, sequence.rewards), sequence.valid)

    def _value_loss(self, rollout: th.Tensor, sequence: Sequence, td_targets: th.Tensor) -> th.Tensor:
        """Two-hot cross-entropy of every Q head against the TD targets, averaged."""
        logits = self.world_model.q(rollout[:-1], sequence.actions)
        cross_entropy = self.world_model.two_hot.cross_entropy(logits, td_targets.expand(logits.shape[:-1]))
        return self._over_horizon(cross_entropy.mean(0), sequence.valid)

    def _over_horizon(self, values: th.Tensor, valid: th.Tensor) -> th.Tensor:
        """Per-step losses ``(H, B)`` averaged over the valid samples, weighted ``rho**t`` and averaged over ``H``."""
        weights = self.rho ** th.arange(self.horizon, device=self.device, dtype=th.float32)
        return (weights * masked_mean(values, valid)).sum() / self.horizon

    def _policy_loss(self, latents: th.Tensor, valid: th.Tensor) -> th.Tensor:
        """Max-entropy policy prior on Q scaled by its running range (updated here)."""
        model = self.world_model
        sample = model.pi(latents)
        q_values = model.q_value(latents, sample.action, reduce="avg")
        update_q_scale(self.policy.q_scale, q_values[0].detach(), self.tau)
        objective = masked_mean(self.entropy_coef * sample.scaled_entropy + q_values / self.policy.q_scale, valid)
        weights = self.rho ** th.arange(latents.shape[0], device=latents.device, dtype=th.float32)
        return -(weights * objective).mean()

    def _sample_action(
        self, learning_starts: int, action_noise: ActionNoise | None = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """Uniform random actions up to step ``learning_starts`` included (TD-MPC2's seed steps 0..S)."""
        return super()._sample_action(learning_starts + 1, action_noise, n_envs)

    def _exploration_action(self, n_envs: int) -> np.ndarray:
        """MPPI planning with exploration noise, warm-started from each env's previous plan."""
        assert self._last_obs is not None, "self._last_obs was not set"
        observations = th.as_tensor(self._last_obs, device=self.device)
        if self._rollout_plan is not None and self._rollout_plan.shape[0] != n_envs:
            self._rollout_plan = None
        actions, self._rollout_plan = self.policy.plan(observations, self._rollout_plan, deterministic=False)
        return actions.cpu().numpy().astype(np.float32)

    def _store_transition(
        self,
        replay_buffer: ReplayBuffer,
        buffer_action: np.ndarray,
        new_obs: np.ndarray | dict[str, np.ndarray],
        reward: np.ndarray,
        dones: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        """SB3's, resetting the warm-start plan of every env whose episode ended."""
        super()._store_transition(replay_buffer, buffer_action, new_obs, reward, dones, infos)
        if self._rollout_plan is not None and dones.any():
            self._rollout_plan[th.as_tensor(dones, device=self._rollout_plan.device)] = 0.0

    def _setup_learn(self, total_timesteps: int, callback: MaybeCallback = None, *args: Any, **kwargs: Any):
        self._rollout_plan = None
        return super()._setup_learn(total_timesteps, callback, *args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_rollout_plan", "_world_model_losses", "_policy_loss"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.optimizer", "policy.pi_optimizer"], []
