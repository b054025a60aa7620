"""SEAR: DrQ-v2 whose encoder is also trained to reconstruct the frames and the agent masks (Gmelin et al., 2023)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import torch as th
from gymnasium import spaces
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.vec_env import VecEnv

from sb3_ef.drqv2.drqv2 import DrQv2
from sb3_ef.drqv2.policies import DrQv2Policy
from sb3_ef.sear.loss import SEAR_LATENT_DIM, SEARLoss, resolve_coefficients

#: DrQv2EF's arguments, which SEAR refuses by name.
EF_ARGUMENTS = frozenset({"beta", "ef_horizon", "babbling_steps", "babbling_mode", "babbling_in_eval"})


class SEARPolicy(DrQv2Policy):
    """:class:`DrQv2Policy` whose encoder projects to SEAR's 4096 features (split by :class:`SEARLoss`)."""

    def __init__(
        self,
        observation_space: spaces.Box,
        action_space: spaces.Box,
        lr_schedule: Schedule,
        features_dim: int | None = SEAR_LATENT_DIM,
        **kwargs: Any,
    ):
        super().__init__(observation_space, action_space, lr_schedule, features_dim=features_dim, **kwargs)


def check_agent_masks(env: VecEnv) -> None:
    """Raise a ``ValueError`` unless every env of ``env`` renders agent masks (``agent_masks`` true)."""
    try:
        flags = env.get_attr("agent_masks")
    except AttributeError:
        flags = [False]
    if not all(flags):
        raise ValueError(
            "SEAR needs an env that renders the agent mask of every frame: build it with "
            "make_env(..., agent_masks=True) (with rl-zoo3: env_kwargs agent_masks: true, also in --env-kwargs, "
            f"which replaces the entry's env_kwargs), got an env whose agent_masks are {flags}"
        )


class SEAR(DrQv2):
    """SEAR (Gmelin et al., ICML 2023): :class:`DrQv2` with :class:`SEARLoss`; other arguments are :class:`DrQv2`'s.

    :param buffer_size: replay buffer capacity in transitions (SEAR's).
    :param replay_buffer_kwargs: extra buffer arguments, as :class:`DrQv2`'s (``store_masks`` is set here).
    :param coefficients: ``"sear"`` (the SEAR authors'), ``"efrl"`` (the EF authors') or a pair, see :class:`SEARLoss`.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"CnnPolicy": SEARPolicy}

    def __init__(
        self,
        policy: str | type[DrQv2Policy],
        env: GymEnv | str,
        *,
        buffer_size: int = 250_000,
        coefficients: str | Sequence[float] = "sear",
        replay_buffer_kwargs: dict[str, Any] | None = None,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        ef_arguments = sorted(set(kwargs) & EF_ARGUMENTS)
        if ef_arguments:
            raise TypeError(
                f"SEAR takes no Ego-Foresight argument, got {ef_arguments}: SEAR is DrQ-v2 with SEAR's own frame and "
                "agent-mask decoders (weighted by coefficients=...); for Ego-Foresight on DrQ-v2 use DrQv2EF"
            )
        resolve_coefficients(coefficients)  # a bad preset or pair fails here, before anything is built
        store_masks = (replay_buffer_kwargs or {}).get("store_masks", True)
        if store_masks is not True:
            raise ValueError(
                f"SEAR reads the agent masks from the replay buffer: replay_buffer_kwargs must not set store_masks "
                f"to {store_masks!r}"
            )
        super().__init__(
            policy,
            env,
            buffer_size=buffer_size,
            replay_buffer_kwargs={**(replay_buffer_kwargs or {}), "store_masks": True},
            _init_setup_model=False,
            **kwargs,
        )
        if self.env is not None:
            check_agent_masks(self.env)
        self.coefficients = coefficients
        if _init_setup_model:
            self._setup_model()

    def set_env(self, env: GymEnv, force_reset: bool = True) -> None:
        """SB3's ``set_env``, refusing an env without agent masks."""
        super().set_env(env, force_reset)
        assert self.env is not None
        check_agent_masks(self.env)

    def _build_auxiliary(self) -> SEARLoss:
        loss = SEARLoss(self.policy.encoder.features_dim, self.observation_space.shape, self.coefficients)  # type: ignore[arg-type]
        # Channels-last decoders in bf16 (1.5x faster updates on a CPU, docs/precision.md); float32 keeps its bits.
        if self.precision == "bf16" and self.policy.channels_last:
            loss.to(memory_format=th.channels_last)  # type: ignore[call-overload]
        return loss
