"""PPO-EF and A2C-EF: SB3's PPO and A2C whose shared encoder Ego-Foresight also trains, its loss joining theirs on
each minibatch (docs/ef.md, "EF on on-policy hosts")."""

from __future__ import annotations

from typing import Any, ClassVar, TypeVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import A2C, PPO
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.policies import (
    ActorCriticCnnPolicy,
    ActorCriticPolicy,
    BasePolicy,
    MultiInputActorCriticPolicy,
)
from stable_baselines3.common.preprocessing import is_image_space
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback, RolloutBufferSamples
from stable_baselines3.common.utils import explained_variance
from stable_baselines3.common.vec_env import VecEnv, VecFrameStack, unwrap_vec_wrapper
from torch.nn import functional as F

from sb3_ef.auxiliary.host import gradient_norm
from sb3_ef.common.buffers.rollout_windows import (
    RolloutRing,
    RolloutWindow,
    RolloutWindows,
    action_encoding_dim,
    encode_actions,
    rollout_minibatches,
)
from sb3_ef.common.env_checks import policy_observation_space
from sb3_ef.common.precision import autocast, float32_outputs
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.ef.babbling import babble_env_actions
from sb3_ef.ef.host import EFBaseMixin
from sb3_ef.ef.losses import ForesightLoss
from sb3_ef.sb3_hosts.ef_hosts import float_features, normalized_features

SelfOnPolicyEF = TypeVar("SelfOnPolicyEF", bound="OnPolicyEFMixin")


def frames_per_observation(env: VecEnv) -> int:
    """Frames stacked in one observation: a ``VecFrameStack``'s (rl-zoo3's ``frame_stack``, SB3's Atari examples),
    else the env's ``frame_stack`` attribute (sb3-ef's envs), else 1."""
    stack = unwrap_vec_wrapper(env, VecFrameStack)
    if stack is not None:
        return int(stack.stacked_obs.n_stack)
    return int(env.get_attr("frame_stack", indices=[0])[0]) if env.has_attr("frame_stack") else 1


def image_keys(space: spaces.Dict) -> list[str]:
    """The keys of a Dict observation space that SB3's ``CombinedExtractor`` reads as images."""
    return [key for key, subspace in space.spaces.items() if is_image_space(subspace, check_channels=False)]


def ef_image_key(space: spaces.Space, key: str | None, multi_input: bool, algorithm: str) -> str | None:
    """The Dict observations' key whose frames EF predicts: ``key``, or the only image key; ``None`` for one image
    observation (``CnnPolicy``)."""
    if not isinstance(space, spaces.Dict):
        if multi_input or key is not None:
            what = "MultiInputPolicy" if multi_input else f"ef_image_key={key!r}"
            raise ValueError(f"{algorithm}: {what} reads Dict observations, got {space}: use CnnPolicy")
        return None
    images = image_keys(space)
    if key is None and len(images) == 1:
        return images[0]
    if key is None or key not in images:
        received = "none" if key is None else f"{key!r}" + (f", a {space[key]}" if key in space.spaces else "")
        raise ValueError(
            f"{algorithm} predicts the frames of one image key of the Dict observations (a uint8 Box (channels, "
            f"height, width) with bounds 0 and 255): expected ef_image_key to name one of {images}, got {received}"
        )
    return key


def check_image_observations(space: spaces.Space, algorithm: str) -> None:
    """Refuse observations that are not one image of stacked uint8 frames, channels first (as SB3 gives them)."""
    if not (isinstance(space, spaces.Box) and space.dtype == np.uint8 and len(space.shape) == 3):
        raise ValueError(
            f"{algorithm} needs image observations: a uint8 Box (channels, height, width) of stacked frames "
            f"(channels last is transposed by SB3), got {space}"
        )


class OnPolicyEFMixin(EFBaseMixin):
    """Adds Ego-Foresight to an SB3 on-policy algorithm with ``CnnPolicy`` or ``MultiInputPolicy``: ``class
    PPOEF(OnPolicyEFMixin, PPO)``.

    :param beta: weight of the EF loss, added to the host's loss on each minibatch (its gradient clipped apart to
        ``beta * max_grad_norm``: ``beta`` sets EF's pull on the shared encoder against the host's, docs/ef.md).
    :param ef_horizon: EF's horizon H, at most ``n_steps * ef_rollouts``.
    :param ef_rollouts: rollouts EF's windows are cut from: a ring of the last ones, drawn uniformly and encoded
        apart; 1, the current one, where they start at the minibatch's steps (one encoder pass serves both losses).
    :param agent_dim: size of h_a, the first features of the policy's shared features extractor.
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight`.
    :param frame_channels: channels of one frame (``None``: the observation's channels over the frames stacked).
    :param ef_image_key: with Dict observations (``MultiInputPolicy``), the image key whose frames EF predicts
        (``None``: the only image key).
    :param babbling_steps: motor babbling at the start: rollouts of random actions that train EF alone (0: none).
    :param babbling_mode: ``"sign"`` or ``"clamped_uniform"`` for Box actions (discrete ones are drawn uniformly).
    :param check_finite_losses: raise a ``ValueError`` naming a NaN or infinite loss before its step.
    :param precision: ``"fp32"`` or ``"bf16"``: the updates' matrix maths in bfloat16 (docs/precision.md).
    """

    rollout_buffer: Any
    max_grad_norm: float
    n_steps: int
    n_envs: int
    _last_obs: Any
    _last_episode_starts: Any
    #: ``log_interval`` of ``learn`` (rollouts between logs), as the host's own ``learn`` defaults it.
    default_log_interval: ClassVar[int] = 1
    auxiliary_module: ForesightLoss | None = None
    _babbling_rng: np.random.Generator | None = None
    _ef_ring: RolloutRing

    def __init__(
        self,
        policy: str | type[ActorCriticPolicy],
        env: GymEnv | str,
        *,
        beta: float = 1.0,
        ef_horizon: int = 10,
        ef_rollouts: int = 4,
        agent_dim: int = 32,
        ef_kwargs: dict[str, Any] | None = None,
        frame_channels: int | None = None,
        ef_image_key: str | None = None,
        babbling_steps: int = 0,
        babbling_mode: str = "sign",
        check_finite_losses: bool = False,
        precision: str = "fp32",
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        name = type(self).__name__
        check_algorithm_arguments(type(self), locals())
        self._keep_ef_arguments(beta, ef_horizon, babbling_steps, babbling_mode, ef_kwargs)
        if env is not None:
            env = maybe_make_env(env, kwargs.get("verbose", 0))
            if not isinstance(env.observation_space, spaces.Dict):  # a Dict's image key is chosen in _setup_model
                check_image_observations(policy_observation_space(env.observation_space), name)
            action_encoding_dim(env.action_space)  # raises for a space EF cannot encode, naming those it can
        super().__init__(policy, env, _init_setup_model=False, **kwargs)  # type: ignore[call-arg]
        if not isinstance(ef_rollouts, int) or ef_rollouts < 1 or ef_horizon > self.n_steps * ef_rollouts:
            raise ValueError(
                f"{name} cuts EF's windows from its last ef_rollouts rollouts: expected an integer ef_rollouts >= 1 "
                f"and ef_horizon <= n_steps * ef_rollouts = {self.n_steps} * {ef_rollouts}, got ef_horizon={ef_horizon}"
            )
        self.ef_rollouts, self.agent_dim = ef_rollouts, agent_dim
        self.ef_kwargs = dict(ef_kwargs or {})
        self.frame_channels, self.ef_image_key = frame_channels, ef_image_key
        self.check_finite_losses = check_finite_losses
        self.precision = precision
        self.babbling = False  # whether the last rollout babbled
        if _init_setup_model:
            self._setup_model()

    @property
    def auxiliary(self) -> ForesightLoss | None:
        """EF's loss, kept on the algorithm (``auxiliary_module``): the policy is SB3's own."""
        return self.auxiliary_module

    @property
    def image_space(self) -> spaces.Space:
        """The observations EF's frames are cut from: the observation space, or its ``ef_image_key``'s."""
        space = self.observation_space
        return space[self.ef_image_key] if isinstance(space, spaces.Dict) and self.ef_image_key else space

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """``(channels, height, width)`` of one frame: EF predicts the newest frame of the stack."""
        if self.frame_channels is None:
            raise ValueError(f"{type(self).__name__} was built without an env: pass frame_channels")
        _, height, width = self.image_space.shape  # type: ignore[misc]
        return self.frame_channels, height, width

    def _check_frames(self) -> None:
        """Choose the image key of Dict observations and the frame's channels (``ef_image_key`` and ``frame_channels``
        as given or saved, else read from the env; here, so that ``load`` checks them against its env)."""
        multi_input = issubclass(self.policy_class, MultiInputActorCriticPolicy)  # type: ignore[attr-defined]
        name = type(self).__name__
        self.ef_image_key = ef_image_key(self.observation_space, self.ef_image_key, multi_input, name)
        channels = self.image_space.shape[0]  # type: ignore[index]
        assert self.env is not None
        frame_channels = self.frame_channels or channels // frames_per_observation(self.env)
        if not isinstance(frame_channels, int) or frame_channels < 1 or channels % frame_channels:
            raise ValueError(f"frame_channels must divide the observation's {channels} channels, got {frame_channels}")
        self.frame_channels = frame_channels

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of the policy's shared features extractor for uint8 stacked observations."""
        return self.policy.extract_features(observations.to(self.device))

    def _setup_model(self) -> None:
        """SB3's setup, then EF's loss, the ring of rollouts EF's windows are cut from, and the babbling generator."""
        if self.env is not None:
            self._check_frames()
        super()._setup_model()
        auxiliary = self._build_auxiliary()
        self.auxiliary_module = auxiliary.to(self.device)  # on the algorithm: the policy stays SB3's own
        # EF's modules step in the policy's Adam, in a group of their own (the encoder is in SB3's group): one step
        # per minibatch on the host's clipped gradient plus EF's (_step).
        self.policy.optimizer.add_param_group({"name": "auxiliary", "params": list(auxiliary.parameters())})
        if self.precision == "bf16":  # SB3's distributions and value loss read float32 heads
            float32_outputs(self.policy.action_net, self.policy.value_net)
        space = self.observation_space
        self._ef_ring = RolloutRing(self.ef_rollouts, image_keys(space) if isinstance(space, spaces.Dict) else ())
        if self._babbling_rng is None:
            self._babbling_rng = np.random.default_rng(self.seed)

    def _build_auxiliary(self) -> ForesightLoss:
        """EF on the shared features extractor, built in a forked generator so that the host's draws stay SB3's."""
        if not self.policy.share_features_extractor:
            raise ValueError(
                f"{type(self).__name__} trains EF on the features the actor and critic share: leave policy_kwargs "
                "share_features_extractor at True"
            )
        if self.ef_image_key is not None and self.ef_kwargs.get("target") == "latent":
            raise ValueError(
                f"{type(self).__name__} with Dict observations trains pixel EF: latent EF's target encodes the whole "
                f"observation at t+k, whose other keys the windows do not keep; expected ef_kwargs target 'pixel', "
                "got 'latent'"
            )
        encoder = self.policy.features_extractor
        encode = normalized_features if self.policy.normalize_images else float_features  # as extract_features
        with th.random.fork_rng(devices=[]):
            return self._foresight_loss(
                encoder, encoder.features_dim, self.agent_dim, self.ef_kwargs, encode=encode,
                action_dim=action_encoding_dim(self.action_space),
            )  # fmt: skip

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_ef_ring"]  # rollouts are not saved (SB3's rollout buffer is not)

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()  # type: ignore[misc]
        return [*state_dicts, "auxiliary_module"], variables

    def learn(
        self: SelfOnPolicyEF,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int | None = None,
        tb_log_name: str | None = None,
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfOnPolicyEF:
        """SB3's ``learn`` (``log_interval``: rollouts, the host's default); refuses babbling through the whole run."""
        final_step = int(total_timesteps) + (0 if reset_num_timesteps else self.num_timesteps)
        start = 0 if reset_num_timesteps else self.num_timesteps
        if start < self.babbling_steps and self.babbling_steps >= final_step:
            raise ValueError(
                f"babbling_steps={self.babbling_steps} must be below the {final_step} steps this learn call reaches: "
                "babbling rollouts train EF alone, so the policy would never train"
            )
        interval = self.default_log_interval if log_interval is None else log_interval
        return super().learn(total_timesteps, callback, interval, tb_log_name, reset_num_timesteps, progress_bar)

    def collect_rollouts(self, env: VecEnv, callback: BaseCallback, rollout_buffer: Any, n_rollout_steps: int) -> bool:
        """SB3's; while ``num_timesteps < babbling_steps`` at its start, the rollout's actions are random (babbling)."""
        self.babbling = self.num_timesteps < self.babbling_steps
        if self.babbling_steps > 0:
            self.logger.record("rollout/babbling", float(self.babbling))
        if not self.babbling:
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)  # type: ignore[misc]
        self.policy.forward = self._babbling_forward  # SB3 acts with self.policy(obs)
        try:
            return super().collect_rollouts(env, callback, rollout_buffer, n_rollout_steps)  # type: ignore[misc]
        finally:
            del self.policy.forward

    def _babbling_forward(self, obs: th.Tensor, deterministic: bool = False) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """The policy's ``forward`` while babbling: random env actions; zero values and log-probabilities (unused)."""
        assert self._babbling_rng is not None
        n_envs = self.n_envs  # obs may be a dict
        actions = babble_env_actions(self._babbling_rng, self.action_space, n_envs, self.babbling_mode)
        zeros = th.zeros(n_envs, device=self.device)
        return th.as_tensor(actions, device=self.device), zeros[:, None], zeros

    def _rollout_windows(self) -> RolloutWindows:
        """EF's windows of the ring with the rollout just collected (read before SB3's ``get`` flattens the buffer)."""
        buffer = self.rollout_buffer
        if buffer.generator_ready:
            raise RuntimeError("train() reads a rollout once: collect a new one first (SB3's learn does)")
        actions = encode_actions(th.as_tensor(buffer.actions), self.action_space)
        self._ef_ring.add(buffer.observations, actions, buffer.episode_starts, self.device)
        return self._ef_ring.windows(
            self._last_obs, self._last_episode_starts, self.frame_shape[0], self.ef_horizon, self.ef_image_key
        )

    def _ef_loss_at(
        self, windows: RolloutWindows, indices: np.ndarray, data: RolloutBufferSamples
    ) -> tuple[th.Tensor, th.Tensor, dict[str, th.Tensor]]:
        """:meth:`_ef_loss` of the windows at the minibatch's steps (one rollout), or of as many drawn from the ring,
        with the features the host's loss reads (then from a pass of their own)."""
        if self.ef_rollouts == 1:
            return self._ef_loss(windows(indices))
        drawn = th.randint(windows.size, (len(indices),), generator=self._auxiliary_generator)
        features, loss, logs = self._ef_loss(windows(drawn.numpy()))
        return features if self.babbling else self.policy.extract_features(data.observations), loss, logs

    def _ef_loss(self, window: RolloutWindow) -> tuple[th.Tensor, th.Tensor, dict[str, th.Tensor]]:
        """EF's calls: the shared features of the window's observations (unshifted, the minibatch's own, so that the
        host's loss reads the same features; with Dict observations every key's), ``beta * L_ef`` and its logs."""
        assert self.auxiliary is not None
        observations = window.observations
        images = observations[self.ef_image_key] if isinstance(observations, dict) else observations  # type: ignore[index]
        _, targets = self.auxiliary.prepare(window._replace(observations=images), 0, self._auxiliary_generator)  # type: ignore[arg-type]
        features = self.policy.extract_features(observations)
        loss, logs = self.auxiliary(features, targets)
        return features, loss, logs

    def _step(self, host_loss: th.Tensor | None, ef_loss: th.Tensor) -> dict[str, th.Tensor]:
        """One step of the policy's optimiser on the host's gradient, clipped as SB3 clips it (over the policy), plus
        EF's, clipped apart (over the encoder and EF) to ``beta * max_grad_norm``; ``host_loss=None`` steps EF alone.
        ``ef_loss`` is ``beta * L_ef``, so that EF's gradient is its own clipped as the host's is, times ``beta``."""
        assert self.auxiliary is not None
        self._check_finite(ef_loss=ef_loss, **({} if host_loss is None else {"loss": host_loss}))
        encoder = list(self.policy.features_extractor.parameters())
        self.policy.optimizer.zero_grad()
        ef_loss.backward(retain_graph=host_loss is not None)
        ef_params = [*encoder, *self.auxiliary.parameters()]
        logs = {"ef_grad_norm": th.nn.utils.clip_grad_norm_(ef_params, self.beta * self.max_grad_norm)}
        if host_loss is not None:
            ef_grads = [param.grad for param in encoder]
            self.policy.zero_grad()  # the policy's parameters: EF's own keep their gradients
            host_loss.backward()
            logs["grad_norm"] = th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm)
            host_norm = gradient_norm(encoder)
            for param, grad in zip(encoder, ef_grads, strict=True):
                if grad is not None:
                    param.grad = grad if param.grad is None else param.grad.add_(grad)
            ef_norm = th.nn.utils.get_total_norm([grad for grad in ef_grads if grad is not None])
            logs["aux_grad_ratio"] = self._averaged_aux_grad_ratio(ef_norm / host_norm.clamp_min(1e-12))
        self.policy.optimizer.step()
        self.auxiliary.after_update(self.policy.features_extractor)
        return logs

    def _evaluate_actions(
        self, features: th.Tensor, data: RolloutBufferSamples
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor | None]:
        """SB3's ``ActorCriticPolicy.evaluate_actions`` from the shared features: values, log-probabilities, entropy."""
        actions = data.actions
        if isinstance(self.action_space, spaces.Discrete):
            actions = actions.long().flatten()
        latent_pi, latent_vf = self.policy.mlp_extractor(features)
        distribution = self.policy._get_action_dist_from_latent(latent_pi)
        return self.policy.value_net(latent_vf).flatten(), distribution.log_prob(actions), distribution.entropy()

    def _record_value_fit(self) -> None:
        """SB3's ``explained_variance`` and ``std`` logs of a round."""
        buffer = self.rollout_buffer
        self.logger.record(
            "train/explained_variance", explained_variance(buffer.values.flatten(), buffer.returns.flatten())
        )
        if hasattr(self.policy, "log_std"):
            self.logger.record("train/std", th.exp(self.policy.log_std).mean().item())


def entropy_loss(log_prob: th.Tensor, entropy: th.Tensor | None) -> th.Tensor:
    """SB3's entropy loss: minus the entropy, or its estimate ``-mean(-log_prob)`` when it has no closed form."""
    return -th.mean(-log_prob) if entropy is None else -th.mean(entropy)


class PPOEF(OnPolicyEFMixin, PPO):
    """PPO (Schulman et al., 2017) from stacked frames with Ego-Foresight (arguments: :class:`OnPolicyEFMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "CnnPolicy": ActorCriticCnnPolicy,
        "MultiInputPolicy": MultiInputActorCriticPolicy,
    }

    def train(self) -> None:
        """SB3's ``PPO.train`` with EF's loss joining each minibatch's; a babbling rollout trains EF alone."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        clip_range = self.clip_range(self._current_progress_remaining)  # type: ignore[operator]
        clip_range_vf = None if self.clip_range_vf is None else self.clip_range_vf(self._current_progress_remaining)  # type: ignore[operator]
        with autocast(self.precision, self.device):
            windows = self._rollout_windows()
            updates: list[dict[str, th.Tensor]] = []
            continue_training = True
            for epoch in range(self.n_epochs):
                for indices, data in rollout_minibatches(self.rollout_buffer, self.batch_size):
                    features, ef_loss, logs = self._ef_loss_at(windows, indices, data)
                    loss = None
                    if not self.babbling:
                        loss, ppo_logs = self._ppo_loss(data, features, clip_range, clip_range_vf)
                        logs.update(ppo_logs)
                        if self.target_kl is not None and ppo_logs["approx_kl"] > 1.5 * self.target_kl:
                            continue_training = False
                            if self.verbose >= 1:
                                kl = ppo_logs["approx_kl"]
                                print(f"Early stopping at step {epoch} due to reaching max kl: {kl:.2f}")
                            break
                    logs.update(self._step(loss, ef_loss))
                    updates.append(logs)
                self._n_updates += 1
                if not continue_training:
                    break
        self._record_updates(updates)
        if not self.babbling:
            self._record_value_fit()
            self.logger.record("train/clip_range", clip_range)
            if clip_range_vf is not None:
                self.logger.record("train/clip_range_vf", clip_range_vf)

    def _ppo_loss(
        self, data: RolloutBufferSamples, features: th.Tensor, clip_range: float, clip_range_vf: float | None
    ) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """SB3's PPO loss of one minibatch from the shared ``features``, and its logged parts."""
        values, log_prob, entropy = self._evaluate_actions(features, data)
        advantages = data.advantages
        if self.normalize_advantage and len(advantages) > 1:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        ratio = th.exp(log_prob - data.old_log_prob)
        clipped_ratio = th.clamp(ratio, 1 - clip_range, 1 + clip_range)
        policy_loss = -th.min(advantages * ratio, advantages * clipped_ratio).mean()
        if clip_range_vf is not None:
            values = data.old_values + th.clamp(values - data.old_values, -clip_range_vf, clip_range_vf)
        value_loss = F.mse_loss(data.returns, values)
        entropy_term = entropy_loss(log_prob, entropy)
        loss = policy_loss + self.ent_coef * entropy_term + self.vf_coef * value_loss
        with th.no_grad():
            log_ratio = log_prob - data.old_log_prob
            logs = {
                "policy_gradient_loss": policy_loss.detach(), "value_loss": value_loss.detach(),
                "entropy_loss": entropy_term.detach(), "loss": loss.detach(),
                "clip_fraction": th.mean((th.abs(ratio - 1) > clip_range).float()),
                "approx_kl": th.mean((th.exp(log_ratio) - 1) - log_ratio),
            }  # fmt: skip
        return loss, logs


class A2CEF(OnPolicyEFMixin, A2C):
    """A2C (Mnih et al., 2016) from stacked frames with Ego-Foresight (arguments: :class:`OnPolicyEFMixin`)."""

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {
        "CnnPolicy": ActorCriticCnnPolicy,
        "MultiInputPolicy": MultiInputActorCriticPolicy,
    }
    default_log_interval = 100

    def train(self) -> None:
        """SB3's ``A2C.train`` (one update on the whole rollout) with EF's loss joining it; a babbling rollout trains
        EF alone."""
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        with autocast(self.precision, self.device):
            windows = self._rollout_windows()
            for indices, data in rollout_minibatches(self.rollout_buffer, None):  # one minibatch, as SB3's A2C
                features, ef_loss, logs = self._ef_loss_at(windows, indices, data)
                loss = None
                if not self.babbling:
                    loss, a2c_logs = self._a2c_loss(data, features)
                    logs.update(a2c_logs)
                logs.update(self._step(loss, ef_loss))
        self._n_updates += 1
        self._record_updates([logs])
        if not self.babbling:
            self._record_value_fit()

    def _a2c_loss(self, data: RolloutBufferSamples, features: th.Tensor) -> tuple[th.Tensor, dict[str, th.Tensor]]:
        """SB3's A2C loss of the rollout from the shared ``features``, and its logged parts."""
        values, log_prob, entropy = self._evaluate_actions(features, data)
        advantages = data.advantages
        if self.normalize_advantage:
            advantages = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
        policy_loss = -(advantages * log_prob).mean()
        value_loss = F.mse_loss(data.returns, values)
        entropy_term = entropy_loss(log_prob, entropy)
        loss = policy_loss + self.ent_coef * entropy_term + self.vf_coef * value_loss
        logs = {"policy_loss": policy_loss, "value_loss": value_loss, "entropy_loss": entropy_term}
        return loss, {key: value.detach() for key, value in logs.items()}
