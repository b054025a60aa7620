"""CURL (Laskin et al., ICML 2020): the authors' pixel SAC with CURL's contrastive loss, with SB3's interface."""

from __future__ import annotations

import itertools
from typing import Any, ClassVar, NamedTuple

import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import polyak_update
from torch.nn import functional as F

from sb3_ef.auxiliary.host import aux_grad_ratio_due, gradient_norm, gradient_norm_ratio
from sb3_ef.auxiliary.momentum import momentum_update
from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.common.layers import frozen
from sb3_ef.common.precision import autocast
from sb3_ef.curl.crop import check_crop_size, random_crops
from sb3_ef.curl.loss import CURLLoss
from sb3_ef.curl.policies import CURLActor, CURLPolicy
from sb3_ef.sb3_hosts.step import AuxiliaryStepMixin


class CURLBatch(NamedTuple):
    """One update's batch, cropped as the authors' ``sample_cpc`` crops it."""

    observations: th.Tensor  # crop of obs t: the critic's, the actor's and CURL's anchor
    actions: th.Tensor
    rewards: th.Tensor
    next_observations: th.Tensor  # a crop of its own of obs t + n
    dones: th.Tensor
    discounts: th.Tensor
    positives: th.Tensor  # a second crop of obs t, through the key encoder


def _curl_policy_kwargs(policy_kwargs: dict[str, Any] | None, crop_size: int, features_dim: int) -> dict[str, Any]:
    """``policy_kwargs`` with CURL's encoder sizes, as the constructor passes them and the saved model records."""
    policy_kwargs = dict(policy_kwargs or {})
    policy_kwargs["features_extractor_kwargs"] = {
        "features_dim": features_dim,
        **(policy_kwargs.get("features_extractor_kwargs") or {}),
        "crop_size": crop_size,
    }
    return policy_kwargs


class CURL(AuxiliaryStepMixin, SAC):
    """CURL (Laskin et al., ICML 2020), the authors' ``CurlSacAgent.update`` (docs/curl.md); other arguments SAC's.

    :param crop_size: side of the random crops, at most the frame size.
    :param encoder_tau: momentum of the critic target's encoder (CURL's key encoder).
    :param features_dim: size of :class:`CURLEncoder`'s features (its other options via ``policy_kwargs``).
    :param actor_update_interval: the actor and temperature learn every this many updates.
    :param alpha_learning_rate: the temperature's Adam learning rate.
    :param alpha_beta: the temperature's Adam beta1 (beta2 0.999).
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": CURLPolicy}
    policy: CURLPolicy
    actor: CURLActor
    auxiliary_module: CURLLoss | None
    encoder_optimizer: th.optim.Optimizer

    def __init__(
        self,
        policy: str | type[CURLPolicy],
        env: GymEnv | str | None,
        *,
        learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 100_000,
        learning_starts: int = 1000,
        batch_size: int = 128,
        tau: float = 0.01,
        ent_coef: str | float = "auto_0.1",
        target_update_interval: int = 2,
        crop_size: int = 84,
        encoder_tau: float = 0.05,
        features_dim: int = 50,
        actor_update_interval: int = 2,
        alpha_learning_rate: float = 1e-4,
        alpha_beta: float = 0.5,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        if "shift_pad" in kwargs:
            raise ValueError("CURL's augmentation is the random crop (crop_size): shift_pad is not a CURL argument")
        if kwargs.get("use_sde"):
            raise ValueError("CURL's actor is the authors' Gaussian: use_sde (gSDE) is not supported")
        if isinstance(policy, type) and not issubclass(policy, CURLPolicy):
            raise ValueError(f"CURL's policy must be 'CnnPolicy' or a CURLPolicy (sub)class, got {policy.__name__}")
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            ent_coef=ent_coef,
            target_update_interval=target_update_interval,
            policy_kwargs=_curl_policy_kwargs(kwargs.pop("policy_kwargs", None), crop_size, features_dim),
            _init_setup_model=False,
            **kwargs,
        )
        self.crop_size = crop_size
        self.encoder_tau = encoder_tau
        self.features_dim = features_dim
        self.actor_update_interval = actor_update_interval
        self.alpha_learning_rate = alpha_learning_rate
        self.alpha_beta = alpha_beta
        if _init_setup_model:
            self._setup_model()

    def _check_curl_arguments(self) -> None:
        """CURL's arguments against the frames (here, not in ``__init__``, so that ``load`` checks them too)."""
        _, height, width = self.observation_space.shape  # type: ignore[misc]
        check_crop_size(self.crop_size, height, width, "CURL")
        for name in ("actor_update_interval", "target_update_interval"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"CURL's {name} must be a positive int, got {value!r}")
        ranges = {
            "encoder_tau": (lambda value: 0.0 < value <= 1.0, "in (0, 1]"),
            "alpha_learning_rate": (lambda value: value > 0.0, "> 0"),
            "alpha_beta": (lambda value: 0.0 <= value < 1.0, "(the temperature's Adam beta1) in [0, 1)"),
        }
        for name, (valid, expected) in ranges.items():
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not valid(value):
                raise ValueError(f"CURL's {name} must be a number {expected}, got {value!r}")

    def _setup_model(self) -> None:
        """SAC's setup with the authors' optimisers of CURL's step: the encoder's own Adam, and an Adam over W with
        the encoder (``auxiliary_optimizer``, made by the SB3 hosts' auxiliary step); the temperature's Adam."""
        self._check_curl_arguments()
        super()._setup_model()
        self.encoder_optimizer = th.optim.Adam(
            self.critic.features_extractor.parameters(), lr=self.auxiliary_optimizer.defaults["lr"]
        )
        if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
            self.ent_coef_optimizer = th.optim.Adam(
                [self.log_ent_coef], lr=self.alpha_learning_rate, betas=(self.alpha_beta, 0.999)
            )

    def _build_auxiliary(self) -> CURLLoss:
        """CURL's loss, W drawn in a forked generator so that SAC's own random draws stay unchanged."""
        with th.random.fork_rng(devices=[]):
            return CURLLoss(
                self.critic.features_extractor, self.crop_size, key_encoder=self.critic_target.features_extractor
            )

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.auxiliary_learning_rate is None:
            optimizers += [self.encoder_optimizer, self.auxiliary_optimizer]
        self._update_learning_rate(optimizers)
        updates = []
        for gradient_step in range(gradient_steps):
            batch = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            with autocast(self.precision, self.device):
                updates.append(self._update(self._crop(batch), step=self._n_updates + gradient_step))  # type: ignore[arg-type]
        self._n_updates += gradient_steps
        self._record_updates(updates)

    def _crop(self, batch: SequenceReplayBufferSamples) -> CURLBatch:
        """The authors' ``sample_cpc`` crops: anchor, positive and next observations."""
        assert self.auxiliary is not None
        anchors, positives = self.auxiliary.prepare(batch, 0, self._auxiliary_generator)
        next_observations = random_crops(batch.next_observations, self.crop_size, self._auxiliary_generator)
        return CURLBatch(
            anchors, batch.actions, batch.rewards, next_observations, batch.dones, batch.discounts, positives
        )

    def _temperature(self) -> th.Tensor:
        if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
            return self.log_ent_coef.detach().exp()
        return self.ent_coef_tensor

    def _update(self, batch: CURLBatch, step: int) -> dict[str, th.Tensor]:
        """One update of the authors' ``CurlSacAgent.update`` (``step``: the update's index over the run)."""
        alpha = self._temperature()
        logs = {"critic_loss": self._critic_step(batch, alpha), "ent_coef": alpha.reshape(())}
        # The critic step's encoder gradient, read now for aux_grad_ratio (no extra pass).
        host_norm = gradient_norm(self.critic.features_extractor.parameters()) if aux_grad_ratio_due(step + 1) else None
        if step % self.actor_update_interval == 0:
            logs.update(self._actor_and_temperature_step(batch.observations, alpha))
        if step % self.target_update_interval == 0:
            heads = [q_network.parameters() for q_network in self.critic.q_networks]
            target_heads = [q_network.parameters() for q_network in self.critic_target.q_networks]
            polyak_update(itertools.chain(*heads), itertools.chain(*target_heads), self.tau)
            encoder, target_encoder = self.critic.features_extractor, self.critic_target.features_extractor
            momentum_update(encoder, target_encoder, self.encoder_tau, "encoder")
        logs.update(self._curl_step(batch, host_norm))
        return logs

    def _critic_step(self, batch: CURLBatch, alpha: th.Tensor) -> th.Tensor:
        """The authors' ``update_critic``; returns the detached loss."""
        with th.no_grad():
            next_actions, next_log_prob = self.actor.action_log_prob(batch.next_observations)
            next_q = th.cat(self.critic_target(batch.next_observations, next_actions), dim=1)
            next_value = next_q.min(dim=1, keepdim=True).values - alpha * next_log_prob
            target = batch.rewards + (1 - batch.dones) * batch.discounts * next_value
        q_values = self.critic(batch.observations, batch.actions)
        loss = sum(F.mse_loss(q_value, target) for q_value in q_values)
        assert isinstance(loss, th.Tensor)
        self._check_finite(critic_loss=loss)
        self.critic.optimizer.zero_grad()
        loss.backward()
        self.critic.optimizer.step()
        return loss.detach()

    def _actor_and_temperature_step(self, observations: th.Tensor, alpha: th.Tensor) -> dict[str, th.Tensor]:
        """The authors' ``update_actor_and_alpha``: the actor through the (frozen) critic, then the temperature."""
        actions, log_prob = self.actor.action_log_prob(observations)
        with frozen(self.critic):
            q_values = th.cat(self.critic(observations, actions), dim=1)
        actor_loss = (alpha * log_prob - q_values.min(dim=1, keepdim=True).values).mean()
        self._check_finite(actor_loss=actor_loss)
        self.actor.optimizer.zero_grad()
        actor_loss.backward()
        self.actor.optimizer.step()
        logs = {"actor_loss": actor_loss.detach()}
        if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
            assert isinstance(self.target_entropy, float)
            ent_coef_loss = (self.log_ent_coef.exp() * (-log_prob - self.target_entropy).detach()).mean()
            self._check_finite(ent_coef_loss=ent_coef_loss)
            self.ent_coef_optimizer.zero_grad()
            ent_coef_loss.backward()
            self.ent_coef_optimizer.step()
            logs["ent_coef_loss"] = ent_coef_loss.detach()
        return logs

    def _curl_step(self, batch: CURLBatch, host_norm: th.Tensor | None = None) -> dict[str, th.Tensor]:
        """The authors' ``update_cpc`` (both Adams on one gradient); logs ``aux_grad_ratio`` given ``host_norm``."""
        assert self.auxiliary is not None
        features = self.critic.extract_features(batch.observations, self.critic.features_extractor)
        loss, logs = self.auxiliary(features, batch.positives)
        self._check_finite(**logs)
        self.encoder_optimizer.zero_grad()
        self.auxiliary_optimizer.zero_grad()
        loss.backward()
        if host_norm is not None:
            ratio = gradient_norm_ratio(self.critic.features_extractor.parameters(), host_norm)
            logs["aux_grad_ratio"] = self._averaged_aux_grad_ratio(ratio)
        self.encoder_optimizer.step()
        self.auxiliary_optimizer.step()
        self.auxiliary.after_update(self.critic.features_extractor)
        return logs

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()
        return [*state_dicts, "encoder_optimizer"], variables

    @classmethod
    def _completed_policy_kwargs(cls, policy_kwargs: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
        completed = _curl_policy_kwargs(policy_kwargs, data.get("crop_size", 84), data.get("features_dim", 50))
        completed.setdefault("use_sde", False)
        return super()._completed_policy_kwargs(completed, data)
