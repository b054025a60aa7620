"""SAC-EF, TD3-EF and TQC-EF: SB3's algorithms, unchanged, plus Ego-Foresight as a step of its own (docs/ef.md)."""

from __future__ import annotations

from typing import Any

import torch as th
from sb3_contrib import TQC
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.type_aliases import GymEnv
from torch import nn

from sb3_ef.ef.host import EFMixin
from sb3_ef.ef.losses import ForesightLoss
from sb3_ef.sb3_hosts.step import AuxiliaryStepMixin


def with_use_sde(policy_kwargs: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
    """``policy_kwargs`` with the ``use_sde`` entry SAC and TQC add to their own."""
    if "use_sde" in policy_kwargs or not isinstance(data.get("use_sde"), bool):
        return policy_kwargs
    return {**policy_kwargs, "use_sde": data["use_sde"]}


class EFStepMixin(EFMixin, AuxiliaryStepMixin):
    """Adds Ego-Foresight to an SB3 off-policy algorithm with a CNN critic encoder: ``class SACEF(EFStepMixin, SAC)``.

    :param beta: weight of the EF loss in its own Adam step.
    :param ef_horizon: EF's prediction horizon H.
    :param agent_dim: size of the agent features, the first features of the critic's encoder.
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight`.
    :param babbling_steps: steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` or ``"clamped_uniform"``.
    :param babbling_in_eval: ``predict`` also babbles while babbling is on.
    """

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        *,
        beta: float = 1.0,
        ef_horizon: int = 10,
        agent_dim: int = 32,
        ef_kwargs: dict[str, Any] | None = None,
        babbling_steps: int = 0,
        babbling_mode: str = "sign",
        babbling_in_eval: bool = False,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        misplaced = sorted({"agent_dim", "ef_kwargs"} & set(kwargs.get("policy_kwargs") or {}))
        if misplaced:
            raise ValueError(
                f"{type(self).__name__} takes {misplaced} as its own arguments ({type(self).__name__}(..., "
                f"{misplaced[0]}=...)), not in policy_kwargs: its policy is the host's own, without EF"
            )
        super().__init__(policy, env, _init_setup_model=False, **kwargs)
        self._init_ef(beta, ef_horizon, babbling_steps, babbling_mode, babbling_in_eval, ef_kwargs)
        self.agent_dim = agent_dim
        self.ef_kwargs = dict(ef_kwargs or {})
        if _init_setup_model:
            self._setup_model()

    def _build_auxiliary(self) -> ForesightLoss:
        """EF on the critic's encoder, built in a forked generator so that the host's draws stay as they are."""
        with th.random.fork_rng(devices=[]):
            encoder = self.critic.features_extractor  # fed SB3's preprocessed observations (extract_features)
            encode = normalized_features if self.critic.normalize_images else float_features
            return self._foresight_loss(encoder, encoder.features_dim, self.agent_dim, self.ef_kwargs, encode=encode)


def normalized_features(encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    """An SB3 features extractor on uint8 images, scaled to [0, 1] as SB3's ``preprocess_obs`` does."""
    return encoder(observations.float() / 255.0)


def float_features(encoder: nn.Module, observations: th.Tensor) -> th.Tensor:
    """An SB3 features extractor on images given as they are (``normalize_images=False``)."""
    return encoder(observations.float())


class SACEF(EFStepMixin, SAC):
    """SAC (Haarnoja et al., 2018) from stacked uint8 frames with Ego-Foresight (arguments: :class:`EFStepMixin`)."""

    @classmethod
    def _completed_policy_kwargs(cls, policy_kwargs: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
        return with_use_sde(policy_kwargs, data)


class TD3EF(EFStepMixin, TD3):
    """TD3 (Fujimoto et al., 2018) from stacked uint8 frames with Ego-Foresight (arguments: :class:`EFStepMixin`)."""


class TQCEF(EFStepMixin, TQC):
    """TQC (Kuznetsov et al., 2020) from stacked uint8 frames with Ego-Foresight (arguments: :class:`EFStepMixin`)."""

    @classmethod
    def _completed_policy_kwargs(cls, policy_kwargs: dict[str, Any], data: dict[str, Any]) -> dict[str, Any]:
        return with_use_sde(policy_kwargs, data)
