"""TD-MPC2, and TDMPC2-EF: TD-MPC2 whose world-model encoder is also trained by Ego-Foresight."""

from __future__ import annotations

from typing import Any, ClassVar, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, Schedule

from sb3_ef.auxiliary.host import AuxiliaryHostMixin
from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.common.augmentation import random_shift
from sb3_ef.common.buffers import SequenceReplayBuffer, SequenceReplayBufferSamples
from sb3_ef.common.compile import CompileOption, compile_kwargs, maybe_compile
from sb3_ef.common.env_checks import FRAME_CHANNELS, check_box_actions, episode_steps, policy_observation_space
from sb3_ef.common.exploration import OwnExplorationMixin
from sb3_ef.common.layers import frozen
from sb3_ef.common.policy_arguments import policy_built_with
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.ef.foresight import ForesightLoss
from sb3_ef.ef.host import EFMixin
from sb3_ef.tdmpc2.math import discount_from_episode_length, seed_steps_from_episode_length
from sb3_ef.tdmpc2.policies import TDMPC2EFPolicy, TDMPC2Policy, check_pixel_space
from sb3_ef.tdmpc2.world_model import WorldModel

SHIFT_PAD = 3
# Set by the algorithm itself, so they cannot come through policy_kwargs.
_ALGORITHM_POLICY_KWARGS = ("horizon", "gamma")


class Sequence(NamedTuple):
    """One training batch laid out over time, as the world model consumes it."""

    first: th.Tensor  # (B, C, h, w) augmented observation at t
    following: th.Tensor  # (H, B, C, h, w) augmented observations at t+1 .. t+H
    actions: th.Tensor  # (H, B, A)
    rewards: th.Tensor  # (H, B)
    valid: th.Tensor  # (H, B) float: step t+i was taken inside the episode
    auxiliary_targets: Any  # the auxiliary loss's targets, augmented with ``first``; None without one


class TDMPC2(AuxiliaryHostMixin, OwnExplorationMixin, OffPolicyAlgorithm):
    """TD-MPC2 (Hansen et al., "TD-MPC2: Scalable, Robust World Models for Continuous Control", ICLR 2024) for
    pixels, a standalone model-based algorithm with SB3's interface.

    TD-MPC2 learns an implicit world model (SimNorm latent, latent dynamics, two-hot reward and Q-ensemble heads)
    with a latent consistency loss, reward and TD-value cross-entropies over a short horizon, a max-entropy policy
    prior on detached latents, and acts by MPPI planning with that model. After ``learning_starts`` seed steps, as
    many updates as seed steps at once (TD-MPC2's pretraining on the seed data), then one gradient update per
    environment step.

    An auxiliary representation loss (a subclass's ``_build_auxiliary``, e.g. :class:`TDMPC2EF`'s Ego-Foresight)
    reads the encoder latent of the first observation; it joins the world model's optimiser (group ``auxiliary``)
    and its gradient is clipped on its own.

    :param policy: ``"CnnPolicy"`` or a :class:`TDMPC2Policy` (sub)class.
    :param env: the environment (uint8 stacked 64x64 RGB frames, channels-first, or channels-last which SB3
        transposes; Box actions) or its id.
    :param learning_rate: Adam learning rate (the encoder uses ``policy_kwargs["encoder_lr_scale"]`` times it).
    :param buffer_size: replay buffer capacity (frames).
    :param learning_starts: seed steps of uniform random actions before the first updates; ``None`` derives them from
        the episode length (TD-MPC2's ``max(1000, 5 x episode length)``, 2500 on DMC).
    :param batch_size: minibatch size.
    :param tau: Polyak coefficient of the target Q-ensemble and of the running Q scale.
    :param gamma: discount; ``None`` derives it from the episode length (TD-MPC2's heuristic, 0.99 on DMC).
    :param horizon: world-model and planning horizon.
    :param consistency_coef: weight of the latent consistency loss.
    :param reward_coef: weight of the reward cross-entropy.
    :param value_coef: weight of the value cross-entropy.
    :param entropy_coef: weight of the policy prior's (action-dim scaled) entropy bonus.
    :param rho: per-step decay of the loss weights over the horizon.
    :param max_grad_norm: gradient clipping: one global norm over the world model for the host's loss (as TD-MPC2),
        one over the encoder and the auxiliary module for an auxiliary loss, one for the policy prior.
    :param seed_burst: when the seed steps end, run as many updates as seed steps at once (TD-MPC2); ``False``: one
        update per step from the start (cheaper on CPU, not the reference's schedule).
    :param check_finite_losses: raise a ``ValueError`` naming the loss when one is NaN or infinite, before the
        optimiser step (one device sync per loss: for debugging).
    :param compile: ``torch.compile`` the update's loss computations (world model and policy prior, forward and
        backward; gradient clipping and the optimiser steps stay eager): ``False`` (eager), ``True`` (default mode),
        a mode name (``"reduce-overhead"``: CUDA graphs) or a dict of ``torch.compile`` arguments. Compiling takes
        minutes at the first update.
    :param replay_buffer_class: a :class:`SequenceReplayBuffer` (sub)class; ``None`` picks it.
    :param replay_buffer_kwargs: extra buffer arguments (``n_steps`` and the window horizon are filled in).
    :param stats_window_size: episodes averaged for the rollout logs.
    :param tensorboard_log: tensorboard log folder (``None``: no tensorboard).
    :param policy_kwargs: see :class:`TDMPC2Policy` (``num_channels``, ``mlp_dim``, ``num_q``, ``planner_kwargs``,
        ...).
    :param verbose: 0 silent, 1 info, 2 debug.
    :param seed: random seed.
    :param device: torch device; ``"auto"`` uses CUDA when available.
    :param _init_setup_model: whether to build the networks at construction.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": TDMPC2Policy}
    policy: TDMPC2Policy
    replay_buffer: SequenceReplayBuffer | None  # _use_sequence_buffer makes SB3 build one

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
        _check_arguments(horizon, policy_kwargs)
        if env is not None:
            env = maybe_make_env(env, verbose)
            check_pixel_space(policy_observation_space(env.observation_space))
            check_box_actions(env.action_space, "TD-MPC2")
        super().__init__(
            policy,
            env,
            learning_rate,
            buffer_size,
            learning_starts,  # type: ignore[arg-type]  # None is resolved in _setup_model
            batch_size,
            tau,
            gamma,  # type: ignore[arg-type]  # None is resolved in _setup_model
            train_freq=1,
            gradient_steps=-1,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=dict(replay_buffer_kwargs or {}),
            policy_kwargs=dict(policy_kwargs or {}),
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Box,),
            support_multi_env=True,
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
        self._rollout_plan: th.Tensor | None = None

        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """SB3's setup with a sequence replay buffer (window :attr:`window`); the planner's horizon and discount are
        passed to the policy from the algorithm's arguments. The losses are compiled in place with ``compile`` (same
        names; gradient clipping and the optimiser steps stay eager)."""
        self._check_episode_length()
        self._derive_seed_steps()
        self._use_sequence_buffer("TD-MPC2 trains on consecutive steps", horizon=self.window, n_steps=1)
        with policy_built_with(self, horizon=self.horizon, gamma=self.gamma):
            super()._setup_model()
        self._world_model_losses = maybe_compile(self._world_model_losses, self.compile)  # type: ignore[method-assign]
        self._policy_loss = maybe_compile(self._policy_loss, self.compile)  # type: ignore[method-assign]

    def _optimise_auxiliary(self, auxiliary: AuxiliaryLoss) -> None:
        """The auxiliary module joins the world model's optimiser as the group ``auxiliary`` (its gradient is
        clipped on its own, see :meth:`_world_model_gradients`)."""
        self.policy.optimizer.add_param_group({"name": "auxiliary", "params": list(auxiliary.parameters())})

    def _check_episode_length(self) -> None:
        """Derive ``gamma`` from the episode length when it is ``None`` (done here, not in ``__init__``, so that
        ``load`` keeps the saved value)."""
        if self.gamma is None:
            steps = None if self.env is None else episode_steps(self.env)
            self.gamma = discount_from_episode_length(_known_episode_steps(steps, "gamma"))

    def _derive_seed_steps(self) -> None:
        """``learning_starts=None``: TD-MPC2's seed steps from the episode length (a saved model keeps its own)."""
        if self.learning_starts is not None:
            return
        steps = None if self.env is None else episode_steps(self.env)
        self.learning_starts = seed_steps_from_episode_length(_known_episode_steps(steps, "learning_starts"))

    @property
    def window(self) -> int:
        """Steps of the replay window: the world-model horizon, or the auxiliary loss's when it is longer."""
        return max(self.horizon, self._auxiliary_horizon())

    @property
    def world_model(self) -> WorldModel:
        """The TD-MPC2 world model (encoder, dynamics, reward, policy prior, Q-ensemble)."""
        return self.policy.world_model

    def train(self, gradient_steps: int, batch_size: int = 256) -> None:
        """TD-MPC2's update (:meth:`_update`): world-model step (encoder, dynamics, reward, Q, and the auxiliary
        module), policy-prior step on detached latents, then the target Q-ensemble."""
        self.policy.set_training_mode(True)
        self._update_learning_rates()
        updates = []
        for _ in range(self._with_seed_burst(gradient_steps)):
            self._n_updates += 1
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            updates.append(self._update(batch))
        self._record_updates(updates)

    def _with_seed_burst(self, gradient_steps: int) -> int:
        """TD-MPC2 pretrains on its seed data: the first round runs ``learning_starts`` updates (when that is more
        than ``gradient_steps``), so that after ``T`` env steps ``T - 1`` updates have run, as in the reference."""
        if self.seed_burst and self._n_updates == 0:
            return max(gradient_steps, self.learning_starts)
        return gradient_steps

    def _update(self, batch: SequenceReplayBufferSamples) -> dict[str, th.Tensor]:
        """One gradient update from one batch; returns the (detached) scalars to log, without a device sync."""
        compiled = self.compile is not False
        if compiled:
            th.compiler.cudagraph_mark_step_begin()
        losses, latents, valid = self.losses(batch)
        self._check_finite(**losses)
        auxiliary_loss = losses.pop("auxiliary_loss", None)
        host_loss = self._host_loss(losses)
        loss = host_loss if auxiliary_loss is None else host_loss + auxiliary_loss
        self.policy.optimizer.zero_grad()
        grad_norms = self._world_model_gradients(host_loss, auxiliary_loss)
        self.policy.optimizer.step()

        with frozen(self.world_model.q_heads):  # only the prior learns from its loss
            pi_loss = self._policy_loss(latents.detach(), valid)
        self._check_finite(pi_loss=pi_loss)
        self.policy.pi_optimizer.zero_grad()
        pi_loss.backward()
        th.nn.utils.clip_grad_norm_(self.world_model.pi_head.parameters(), self.max_grad_norm)
        self.policy.pi_optimizer.step()
        self.world_model.soft_update_target_q(self.tau)
        if self.auxiliary is not None:
            self.auxiliary.after_update(self.world_model.encoder)

        logs = {key: value.detach() for key, value in losses.items()}
        logs.update(total_loss=loss.detach(), pi_loss=pi_loss.detach())
        logs.update(grad_norms)
        logs["q_scale"] = self.policy.q_scale.clone()
        # CUDA graph outputs are overwritten by the next replay: keep copies.
        return {name: value.clone() for name, value in logs.items()} if compiled else logs

    def _host_loss(self, losses: dict[str, th.Tensor]) -> th.Tensor:
        """TD-MPC2's world-model loss: the weighted sum of its consistency, reward and value losses."""
        return (
            self.consistency_coef * losses["consistency_loss"]
            + self.reward_coef * losses["reward_loss"]
            + self.value_coef * losses["value_loss"]
        )

    def _gradient_groups(self) -> tuple[list[th.nn.Parameter], list[th.nn.Parameter]]:
        """The parameters of the host's clip (the world model) and of the auxiliary loss's (the encoder and the
        auxiliary module)."""
        groups = {group["name"]: group["params"] for group in self.policy.optimizer.param_groups}
        host_params = [param for name, params in groups.items() if name != "auxiliary" for param in params]
        return host_params, [*groups["encoder"], *groups.get("auxiliary", [])]

    def _world_model_gradients(self, host_loss: th.Tensor, auxiliary_loss: th.Tensor | None) -> dict[str, th.Tensor]:
        """Backpropagate the world-model losses and clip; returns the gradient norms before clipping.

        The host's gradient gets TD-MPC2's one global clip over the world model (encoder, dynamics, reward, Q).
        The auxiliary loss's gradient (weighted; EF's is summed over pixels: norms in the thousands) is computed
        apart, clipped to the same norm over the encoder and the auxiliary module, and added: one shared clip would
        shrink the host's update by the auxiliary norm."""
        host_params, auxiliary_params = self._gradient_groups()
        auxiliary_grads = None
        if auxiliary_loss is not None:
            auxiliary_grads = th.autograd.grad(auxiliary_loss, auxiliary_params, retain_graph=True, allow_unused=True)
        host_loss.backward()
        norms = {"grad_norm": th.nn.utils.clip_grad_norm_(host_params, self.max_grad_norm)}
        if auxiliary_grads is not None:
            pairs = [
                (param, grad) for param, grad in zip(auxiliary_params, auxiliary_grads, strict=True) if grad is not None
            ]
            auxiliary_norm = th.nn.utils.get_total_norm([grad for _, grad in pairs])
            scale = (self.max_grad_norm / (auxiliary_norm + 1e-6)).clamp(max=1.0)
            for param, grad in pairs:
                if param.grad is None:
                    # In the parameter's memory layout (autograd.grad's may differ: channels-last decoder weights),
                    # which the fused Adam step assumes.
                    param.grad = th.empty_like(param).copy_(grad).mul_(scale)
                else:
                    param.grad.add_(grad * scale)
            norms["auxiliary_grad_norm"] = auxiliary_norm
        return norms

    def losses(self, batch: SequenceReplayBufferSamples) -> tuple[dict[str, th.Tensor], th.Tensor, th.Tensor]:
        """World-model losses of one batch: ``consistency_loss``, ``reward_loss``, ``value_loss``, unweighted; with
        an auxiliary loss also ``auxiliary_loss`` (weighted, as the update adds it) and its logged parts (EF's
        ``ef_loss``, detached). Also the latents ``(H+1, B, L)`` of the model rollout and their validity. The
        augmentation runs eagerly, the rest in :meth:`_world_model_losses` (compiled with ``compile``)."""
        return self._world_model_losses(self._sequence(batch))

    def _world_model_losses(self, sequence: Sequence) -> tuple[dict[str, th.Tensor], th.Tensor, th.Tensor]:
        """The world-model losses, rollout latents and validity of :meth:`losses` from an augmented sequence."""
        model, horizon = self.world_model, self.horizon
        weights = self.rho ** th.arange(horizon, device=self.device, dtype=th.float32)
        with th.no_grad():
            next_latents = model.encode(sequence.following.flatten(0, 1)).unflatten(0, sequence.following.shape[:2])
            next_actions = model.pi(next_latents).action
            td_targets = sequence.rewards + self.gamma * model.q_value(
                next_latents, next_actions, reduce="min", target=True
            )

        first_latent = z = model.encode(sequence.first)
        latents, consistency = [z], []
        for t in range(horizon):
            z = model.next(z, sequence.actions[t])
            consistency.append((z - next_latents[t]).pow(2).mean(-1))
            latents.append(z)
        rollout = th.stack(latents)
        reward_ce = model.two_hot.cross_entropy(model.reward(rollout[:-1], sequence.actions), sequence.rewards)
        q_logits = model.q(rollout[:-1], sequence.actions)
        value_ce = model.two_hot.cross_entropy(q_logits, td_targets.expand(q_logits.shape[:-1])).mean(0)
        losses = {
            "consistency_loss": (weights * _masked_mean(th.stack(consistency), sequence.valid)).sum() / horizon,
            "reward_loss": (weights * _masked_mean(reward_ce, sequence.valid)).sum() / horizon,
            "value_loss": (weights * _masked_mean(value_ce, sequence.valid)).sum() / horizon,
        }
        if self.auxiliary is not None:
            auxiliary_loss, logs = self.auxiliary(first_latent, sequence.auxiliary_targets)
            losses.update(auxiliary_loss=auxiliary_loss, **logs)
        first_valid = th.ones_like(sequence.valid[:1])
        return losses, rollout, th.cat([first_valid, sequence.valid])

    def _sequence(self, batch: SequenceReplayBufferSamples) -> Sequence:
        """Rebuild the stacked observations t+1..t+H from the context and the future frames, and augment: later
        observations get their own shifts, the observation at t is augmented with the auxiliary loss's targets."""
        observations = batch.observations
        size, channels, height, width = observations.shape
        stack = channels // FRAME_CHANNELS
        frames = th.cat(
            [observations.view(size, stack, FRAME_CHANNELS, height, width), batch.future_frames[:, : self.horizon]],
            dim=1,
        )
        following = th.stack([frames[:, t : t + stack].flatten(1, 2) for t in range(1, self.horizon + 1)])
        (following,) = random_shift(following.flatten(0, 1), pad=SHIFT_PAD)
        valid = batch.future_mask[:, : self.horizon].float().cumprod(dim=1).T
        first, auxiliary_targets = self._augment_observations(batch, pad=SHIFT_PAD)
        return Sequence(
            first=first,
            following=following.unflatten(0, (self.horizon, size)),
            actions=batch.future_actions[:, : self.horizon].transpose(0, 1),
            rewards=batch.future_rewards[:, : self.horizon].T,
            valid=valid,
            auxiliary_targets=auxiliary_targets,
        )

    def _policy_loss(self, latents: th.Tensor, valid: th.Tensor) -> th.Tensor:
        """Max-entropy policy prior: maximise Q (scaled by its running 5-95% range) plus the entropy bonus (the
        update freezes the Q-ensemble meanwhile, so that only the prior learns); also updates the running Q
        scale."""
        model = self.world_model
        sample = model.pi(latents)
        q_values = model.q_value(latents, sample.action, reduce="avg")
        self._update_q_scale(q_values[0].detach())
        objective = _masked_mean(self.entropy_coef * sample.scaled_entropy + q_values / self.policy.q_scale, valid)
        weights = self.rho ** th.arange(latents.shape[0], device=latents.device, dtype=th.float32)
        return -(weights * objective).mean()

    def _update_q_scale(self, q_values: th.Tensor) -> None:
        """Move the running scale towards the 5-95 percentile range of Q (at least 1)."""
        low, high = th.quantile(q_values, th.tensor([0.05, 0.95], device=q_values.device))
        self.policy.q_scale.lerp_(th.clamp(high - low, min=1.0), self.tau)

    def _update_learning_rates(self) -> None:
        """Set the current learning rate on both optimisers, keeping each group's relative scale (encoder x0.3)."""
        learning_rate = self.lr_schedule(self._current_progress_remaining)
        self.logger.record("train/learning_rate", learning_rate)
        for optimizer in (self.policy.optimizer, self.policy.pi_optimizer):
            for group in optimizer.param_groups:
                group["lr"] = learning_rate * group.get("lr_scale", 1.0)

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
        """Store as SB3 does; the warm-start plan of every env whose episode ended is reset."""
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


class TDMPC2EF(EFMixin, TDMPC2):
    """TDMPC2-EF (Ego-Foresight on TD-MPC2): the world model is trained by ``L_TDMPC + beta * L_ef``.

    :class:`TDMPC2` plus Ego-Foresight: it reads the encoder latent of the first observation (agent part: the first
    ``agent_dim`` features), rolls the agent part forward with the next ``k`` actions and decodes frame ``t+k``;
    motor babbling (random +-1 actions) fills the first ``babbling_steps`` steps. TD-MPC2's own ``horizon`` stays
    the world model's and the planner's; EF's window is ``ef_horizon``.

    Paper: Nunes et al., "Ego-Foresight: Self-supervised Learning of Agent-Aware Representations for Improved RL"
    (ICLR 2026).

    :param beta: weight of the Ego-Foresight loss (to train without EF, use :class:`TDMPC2`).
    :param ef_horizon: Ego-Foresight prediction horizon H (the rollout length k is drawn in [1, H]).
    :param babbling_steps: steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` (random +-1) or ``"clamped_uniform"``.
    :param babbling_in_eval: ``predict`` also babbles while ``num_timesteps < babbling_steps`` (the EF authors'
        Meta-World evaluation protocol).
    :param policy_kwargs: see :class:`TDMPC2EFPolicy` (``agent_dim``, ``ef_kwargs``, and :class:`TDMPC2Policy`'s).

    The other arguments are :class:`TDMPC2`'s.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": TDMPC2EFPolicy}
    policy: TDMPC2EFPolicy

    def __init__(
        self,
        policy: str | type[TDMPC2EFPolicy],
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
        beta: float = 1.0,
        ef_horizon: int = 10,
        babbling_steps: int = 1250,
        babbling_mode: str = "sign",
        babbling_in_eval: bool = False,
        check_finite_losses: bool = False,
        compile: CompileOption = False,
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
            learning_rate,
            buffer_size,
            learning_starts,
            batch_size,
            tau,
            gamma,
            horizon=horizon,
            consistency_coef=consistency_coef,
            reward_coef=reward_coef,
            value_coef=value_coef,
            entropy_coef=entropy_coef,
            rho=rho,
            max_grad_norm=max_grad_norm,
            seed_burst=seed_burst,
            check_finite_losses=check_finite_losses,
            compile=compile,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            policy_kwargs=policy_kwargs,
            verbose=verbose,
            seed=seed,
            device=device,
            _init_setup_model=False,
        )
        self._init_ef(beta, ef_horizon, babbling_steps, babbling_mode, babbling_in_eval)
        if _init_setup_model:
            self._setup_model()

    def _build_auxiliary(self) -> ForesightLoss:
        """Ego-Foresight on the world model's latent, sized by the policy (``agent_dim``, ``ef_kwargs``)."""
        policy = self.policy
        if not isinstance(policy, TDMPC2EFPolicy):
            raise TypeError(f"TDMPC2EF needs a TDMPC2EFPolicy (EF's sizes), got {type(policy).__name__}")
        return self._foresight(policy.world_model.latent_dim, policy.agent_dim, policy.ef_kwargs, policy.channels_last)


def _masked_mean(values: th.Tensor, valid: th.Tensor) -> th.Tensor:
    """Mean over the batch (last axis) of the valid entries, per leading index: ``(T, B) -> (T,)``."""
    return (values * valid).sum(-1) / valid.sum(-1).clamp(min=1.0)


def _known_episode_steps(steps: int | None, argument: str) -> int:
    """The episode length from which ``argument=None`` is derived; raise naming ``argument`` when it is unknown."""
    if steps is None:
        raise ValueError(
            f"{argument}=None derives its value from the episode length, which this env does not expose "
            f"(no spec.max_episode_steps, TimeLimit, episode_length or max_episode_steps): pass {argument}"
        )
    return steps


def _check_arguments(horizon: int, policy_kwargs: dict[str, Any] | None) -> None:
    if not isinstance(horizon, int) or horizon < 1:
        raise ValueError(f"horizon must be a positive integer, got {horizon!r}")
    reserved = sorted(set(policy_kwargs or {}) & set(_ALGORITHM_POLICY_KWARGS))
    if reserved:
        raise ValueError(f"Pass {reserved} to the algorithm, not in policy_kwargs (they are set from its arguments)")
