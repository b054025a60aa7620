"""CURL's actor and critic as an SB3 SAC policy with the authors' networks (see docs/curl.md, "Networks")."""

from __future__ import annotations

import math
from typing import Any, cast

import torch as th
from gymnasium import spaces
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from stable_baselines3.sac.policies import Actor, SACPolicy
from torch import nn
from torch.nn import functional as F

from sb3_ef.curl.encoder import CURLEncoder, weight_init


class CURLActor(Actor):
    """SB3's SAC actor with the authors' tanh-mapped log-std and initialisation; other arguments SB3's ``Actor``'s.

    :param log_std_min: lowest log-std (the authors' ``actor_log_std_min``).
    :param log_std_max: highest log-std (the authors' ``actor_log_std_max``).
    """

    def __init__(self, *args: Any, log_std_min: float = -10.0, log_std_max: float = 2.0, **kwargs: Any):
        super().__init__(*args, **kwargs)
        if self.use_sde:
            raise ValueError("CURL's actor is the authors' Gaussian: use_sde (gSDE) is not supported")
        if not log_std_min < log_std_max:
            raise ValueError(f"log_std_min must be below log_std_max, got {log_std_min!r} and {log_std_max!r}")
        self.log_std_min, self.log_std_max = float(log_std_min), float(log_std_max)
        self.latent_pi.apply(weight_init)
        heads = cast(tuple[nn.Linear, nn.Linear], (self.mu, self.log_std))
        action_dim = heads[0].out_features
        joint = nn.Linear(heads[0].in_features, 2 * action_dim)
        weight_init(joint)
        with th.no_grad():
            for index, layer in enumerate(heads):
                layer.weight.copy_(joint.weight[index * action_dim : (index + 1) * action_dim])
                layer.bias.zero_()

    def _get_constructor_parameters(self) -> dict[str, Any]:
        bounds = {"log_std_min": self.log_std_min, "log_std_max": self.log_std_max}
        return {**super()._get_constructor_parameters(), **bounds}

    def get_action_dist_params(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor, dict[str, th.Tensor]]:
        """Mean and log-std (tanh-mapped into ``[log_std_min, log_std_max]``) before the squash."""
        latent_pi = self.latent_pi(self.extract_features(obs, self.features_extractor))
        log_std = th.tanh(cast(nn.Linear, self.log_std)(latent_pi))
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (log_std + 1)
        return self.mu(latent_pi), log_std, {}

    def action_log_prob(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        """A squashed Gaussian action and its (batch, 1) log-probability, computed as the authors do."""
        mean, log_std, _ = self.get_action_dist_params(obs)
        noise = th.randn_like(mean)
        action = th.tanh(mean + noise * log_std.exp())
        log_prob = (-0.5 * noise.pow(2) - log_std).sum(-1, keepdim=True) - 0.5 * math.log(2 * math.pi) * noise.size(-1)
        log_prob = log_prob - th.log(F.relu(1 - action.pow(2)) + 1e-6).sum(-1, keepdim=True)
        return action, log_prob


class CURLPolicy(SACPolicy):
    """SB3's ``SACPolicy`` with the authors' CURL networks; other arguments ``SACPolicy``'s.

    :param log_std_min: see :class:`CURLActor`.
    :param log_std_max: see :class:`CURLActor`.
    """

    actor: CURLActor

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        features_extractor_class: type[CURLEncoder] = CURLEncoder,
        features_extractor_kwargs: dict[str, Any] | None = None,
        normalize_images: bool = False,
        share_features_extractor: bool = False,
        log_std_min: float = -10.0,
        log_std_max: float = 2.0,
        **kwargs: Any,
    ):
        if not (isinstance(features_extractor_class, type) and issubclass(features_extractor_class, CURLEncoder)):
            raise ValueError(
                f"CURL's features extractor must be a CURLEncoder (sub)class, got {features_extractor_class!r}"
            )
        if normalize_images:
            raise ValueError("CURLEncoder scales the images itself: CURL needs policy_kwargs normalize_images=False")
        if share_features_extractor:
            raise ValueError(
                "CURL's actor and critic have an encoder each (the actor's convolutions are the critic's): "
                "share_features_extractor must be False"
            )
        self.log_std_bounds = (log_std_min, log_std_max)
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            net_arch=[1024, 1024] if net_arch is None else net_arch,
            features_extractor_class=features_extractor_class,
            features_extractor_kwargs=features_extractor_kwargs,
            normalize_images=normalize_images,
            share_features_extractor=False,
            **kwargs,
        )

    def _build(self, lr_schedule: Schedule) -> None:
        self.actor = self.make_actor()
        self.critic = self.make_critic(features_extractor=None)
        critic_encoder = cast(CURLEncoder, self.critic.features_extractor)
        cast(CURLEncoder, self.actor.features_extractor).share_convolutions(critic_encoder)
        for q_network in self.critic.q_networks:
            q_network.apply(weight_init)
        self.critic_target = self.make_critic(features_extractor=None)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.set_training_mode(False)
        tied = {id(parameter) for parameter in critic_encoder.convnet.parameters()}
        self.actor.optimizer = self.optimizer_class(
            [parameter for parameter in self.actor.parameters() if id(parameter) not in tied],
            lr=lr_schedule(1),  # type: ignore[call-arg]
            **self.optimizer_kwargs,
        )
        self.critic.optimizer = self.optimizer_class(
            self.critic.parameters(),
            lr=lr_schedule(1),  # type: ignore[call-arg]
            **self.optimizer_kwargs,
        )

    def make_actor(self, features_extractor: Any = None) -> CURLActor:
        actor_kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)
        log_std_min, log_std_max = self.log_std_bounds
        return CURLActor(**actor_kwargs, log_std_min=log_std_min, log_std_max=log_std_max).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        log_std_min, log_std_max = self.log_std_bounds
        return {**super()._get_constructor_parameters(), "log_std_min": log_std_min, "log_std_max": log_std_max}
