"""DrQ-v2's encoder (with DrQv2-EF's projection), actor, twin critic and the policies of DrQ-v2 and DrQv2-EF."""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp, get_actor_critic_arch
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from sb3_ef.auxiliary.loss import AuxiliaryLoss, CarriesAuxiliary
from sb3_ef.common.env_checks import FRAME_CHANNELS, check_stacked_frames
from sb3_ef.common.forwarding import base_arguments
from sb3_ef.common.layers import orthogonal_init
from sb3_ef.ef.host import EFPolicyMixin

# Conv stack of DrQ-v2: (kernel, stride) per layer, 32 filters each.
_CONV_LAYERS = ((3, 2), (3, 1), (3, 1), (3, 1))
_POOL = 4


def _conv_output_size(size: int) -> int:
    for kernel, stride in _CONV_LAYERS:
        size = (size - kernel) // stride + 1
    return size


class DrQv2Encoder(BaseFeaturesExtractor):
    """DrQ-v2's conv stack on ``obs / 255 - 0.5``; with ``features_dim``, DrQv2-EF's 4x4 average pool and projection.

    :param observation_space: uint8 Box of shape (3 * frame_stack, height, width).
    :param features_dim: projected feature size; ``None`` keeps DrQ-v2's flattened conv output (39200 at 84x84).
    :param n_filters: channels of every conv layer.
    """

    def __init__(self, observation_space: spaces.Box, features_dim: int | None = 2048, n_filters: int = 32):
        if features_dim is not None and not _is_positive_int(features_dim):
            raise ValueError(
                "features_dim must be a positive integer (or None for the unprojected conv features), "
                f"got {features_dim!r}"
            )
        channels, height, width = check_stacked_frames(observation_space, "DrQ-v2")
        conv_height, conv_width = _conv_output_size(height), _conv_output_size(width)
        divisor = _POOL if features_dim is not None else 1
        if conv_height // divisor < 1 or conv_width // divisor < 1:
            smallest = next(size for size in range(1, 1000) if _conv_output_size(size) // divisor >= 1)
            raise ValueError(
                f"Images of {height}x{width} are too small for the DrQ-v2 encoder"
                f"{' with its pooled projection' if features_dim is not None else ''}: "
                f"expected at least {smallest}x{smallest}"
            )
        conv_dim = n_filters * conv_height * conv_width
        super().__init__(observation_space, features_dim if features_dim is not None else conv_dim)

        layers: list[nn.Module] = []
        in_channels = channels
        for kernel, stride in _CONV_LAYERS:
            layers += [nn.Conv2d(in_channels, n_filters, kernel, stride=stride), nn.ReLU()]
            in_channels = n_filters
        self.convnet = nn.Sequential(*layers)
        self.projection: nn.Module = nn.Flatten()
        if features_dim is not None:
            pooled_dim = n_filters * (conv_height // _POOL) * (conv_width // _POOL)
            self.projection = nn.Sequential(
                nn.AvgPool2d(_POOL, _POOL), nn.Flatten(), nn.Linear(pooled_dim, features_dim)
            )

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.projection(self.convnet(observations.float() / 255.0 - 0.5))


class DrQv2Actor(nn.Module):
    """Deterministic actor: trunk Linear -> LayerNorm -> Tanh, then an MLP with a tanh output (the mean action)."""

    optimizer: th.optim.Optimizer  # set by the policy

    def __init__(self, features_dim: int, action_dim: int, trunk_dim: int, net_arch: list[int]):
        super().__init__()
        self.trunk = nn.Sequential(nn.Linear(features_dim, trunk_dim), nn.LayerNorm(trunk_dim), nn.Tanh())
        self.mu = nn.Sequential(*create_mlp(trunk_dim, action_dim, net_arch, nn.ReLU, squash_output=True))

    def forward(self, features: th.Tensor) -> th.Tensor:
        return self.mu(self.trunk(features))


class DrQv2Critic(nn.Module):
    """Twin Q-function: a trunk as the actor's, then one MLP per Q head on ``[trunk(h), action]``."""

    optimizer: th.optim.Optimizer  # set by the policy (the critic target has none)

    def __init__(self, features_dim: int, action_dim: int, trunk_dim: int, net_arch: list[int], n_critics: int = 2):
        super().__init__()
        self.trunk = nn.Sequential(nn.Linear(features_dim, trunk_dim), nn.LayerNorm(trunk_dim), nn.Tanh())
        self.q_networks = nn.ModuleList(
            nn.Sequential(*create_mlp(trunk_dim + action_dim, 1, net_arch, nn.ReLU)) for _ in range(n_critics)
        )

    def forward(self, features: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        trunk_actions = th.cat([self.trunk(features), actions], dim=1)
        return tuple(q_network(trunk_actions) for q_network in self.q_networks)


def _is_positive_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and bool(value > 0)


def actor_critic_arch(net_arch: list[int] | dict[str, list[int]]) -> tuple[list[int], list[int]]:
    """Hidden sizes of the actor and of each Q head: one list for both, or SB3's ``dict(pi=[...], qf=[...])``."""
    expected = "a list of positive layer sizes (e.g. [1024, 1024]) or dict(pi=[...], qf=[...])"
    if isinstance(net_arch, dict):
        if set(net_arch) != {"pi", "qf"}:
            raise ValueError(f"net_arch as a dict needs exactly the keys 'pi' and 'qf', got {sorted(net_arch)}")
        layers = [*net_arch["pi"], *net_arch["qf"]] if all(isinstance(v, list) for v in net_arch.values()) else None
    else:
        layers = net_arch if isinstance(net_arch, list) else None
    if layers is None or not all(_is_positive_int(size) for size in layers):
        raise ValueError(f"net_arch must be {expected}, got {net_arch!r}")
    return get_actor_critic_arch(net_arch)


class DrQv2Policy(CarriesAuxiliary, BasePolicy):
    """Encoder, actor, critic, critic target and ``auxiliary``; ``critic.optimizer`` trains all but the actor.

    :param observation_space: uint8 Box of shape (3 * frame_stack, height, width).
    :param action_space: Box action space.
    :param lr_schedule: learning rate schedule (the same rate for all networks, as DrQ-v2).
    :param net_arch: hidden sizes of the actor and Q heads, or ``dict(pi=[...], qf=[...])`` for different ones.
    :param trunk_dim: size of the actor's and critic's trunk output.
    :param n_critics: number of Q heads (their minimum is used).
    :param features_dim: encoder projection size, ``None`` for DrQ-v2's unprojected conv features.
    :param optimizer_class: optimiser class.
    :param optimizer_kwargs: optimiser arguments other than the learning rate; ``None`` gives Adam's fused kernel.
    :param channels_last: keep the conv weights (encoder, auxiliary decoder) channels-last (faster convolutions).
    """

    observation_space: spaces.Box
    action_space: spaces.Box

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        net_arch: list[int] | dict[str, list[int]] | None = None,
        trunk_dim: int = 50,
        n_critics: int = 2,
        features_dim: int | None = None,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
        channels_last: bool = True,
    ):
        if optimizer_kwargs is None and optimizer_class is th.optim.Adam:
            optimizer_kwargs = {"fused": True}
        super().__init__(
            observation_space,
            action_space,
            features_extractor_class=DrQv2Encoder,
            features_extractor_kwargs={"features_dim": features_dim},
            normalize_images=False,
            optimizer_class=optimizer_class,
            optimizer_kwargs=optimizer_kwargs,
            squash_output=True,
        )
        self._constructor_kwargs = base_arguments(DrQv2Policy, locals())
        self.net_arch = net_arch if net_arch is not None else [1024, 1024]
        self.actor_arch, self.critic_arch = actor_critic_arch(self.net_arch)
        self.trunk_dim = trunk_dim
        self.n_critics = n_critics
        self.features_dim = features_dim
        self.channels_last = channels_last
        self.auxiliary: AuxiliaryLoss | None = None
        self._build(lr_schedule)

    def _build(self, lr_schedule: Schedule) -> None:
        action_dim = int(np.prod(self.action_space.shape))
        self.encoder = DrQv2Encoder(self.observation_space, features_dim=self.features_dim)
        repr_dim = self.encoder.features_dim
        self.actor = DrQv2Actor(repr_dim, action_dim, self.trunk_dim, self.actor_arch)
        self.critic = DrQv2Critic(repr_dim, action_dim, self.trunk_dim, self.critic_arch, self.n_critics)
        for module in (self.encoder, self.actor, self.critic):
            module.apply(orthogonal_init)
        self.critic_target = DrQv2Critic(repr_dim, action_dim, self.trunk_dim, self.critic_arch, self.n_critics)
        self.critic_target.load_state_dict(self.critic.state_dict())
        self.critic_target.train(False)
        self.critic_target.requires_grad_(False)
        if self.channels_last:
            self.encoder.to(memory_format=th.channels_last)  # type: ignore[call-overload]  # torch's stub lacks it

        representation_params = [*self.encoder.parameters(), *self.critic.parameters()]
        self.critic.optimizer = self.optimizer_class(representation_params, lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]
        self.actor.optimizer = self.optimizer_class(self.actor.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)  # type: ignore[call-arg]

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        """``(3, height, width)`` of one frame."""
        _, height, width = self.observation_space.shape
        return (FRAME_CHANNELS, height, width)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Encoder features h of uint8 stacked observations."""
        return self.encoder(observations)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        data = super()._get_constructor_parameters()
        del data["normalize_images"]  # fixed: the encoder scales images itself
        data.update(
            self._constructor_kwargs,
            net_arch=self.net_arch,
            lr_schedule=self._dummy_schedule,
            optimizer_kwargs=self.optimizer_kwargs,
        )
        return data

    def forward(self, observation: th.Tensor, deterministic: bool = True) -> th.Tensor:
        return self._predict(observation, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = True) -> th.Tensor:
        """The mean action; the algorithm adds exploration noise, so ``deterministic`` is ignored (as in TD3)."""
        assert isinstance(observation, th.Tensor)  # a Box observation space
        return self.actor(self.encode(observation))

    def set_training_mode(self, mode: bool) -> None:
        self.encoder.train(mode)
        self.actor.train(mode)
        self.critic.train(mode)
        if self.auxiliary is not None:
            self.auxiliary.train(mode)
        self.training = mode


class DrQv2EFPolicy(EFPolicyMixin, DrQv2Policy):
    """:class:`DrQv2Policy` with the sizes DrQv2-EF's Ego-Foresight module is built from.

    :param agent_dim: number of leading feature dimensions that are agent features.
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight`.
    :param features_dim: encoder projection size (``None``: DrQ-v2's unprojected conv features).
    :param kwargs: the other arguments of :class:`DrQv2Policy`.
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        agent_dim: int = 32,
        ef_kwargs: dict[str, Any] | None = None,
        features_dim: int | None = 2048,
        **kwargs: Any,
    ):
        super().__init__(
            observation_space, action_space, lr_schedule, agent_dim=agent_dim, ef_kwargs=ef_kwargs,
            features_dim=features_dim, **kwargs,
        )  # fmt: skip
