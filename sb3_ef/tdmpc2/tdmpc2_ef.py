"""TDMPC2-EF: TD-MPC2 whose world-model encoder is also trained by Ego-Foresight."""

from __future__ import annotations

from typing import Any, ClassVar

import torch as th
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule

from sb3_ef.common.compile import CompileOption
from sb3_ef.common.forwarding import base_arguments
from sb3_ef.ef.host import EFMixin
from sb3_ef.ef.losses import ForesightLoss
from sb3_ef.tdmpc2.policies import TDMPC2EFPolicy
from sb3_ef.tdmpc2.tdmpc2 import TDMPC2
from sb3_ef.tdmpc2.world_model import encode_frames


class TDMPC2EF(EFMixin, TDMPC2):
    """:class:`TDMPC2` also trained by Ego-Foresight on the first latent (docs/tdmpc2.md); other arguments as TDMPC2's.

    :param beta: weight of the Ego-Foresight loss (to train without EF, use :class:`TDMPC2`).
    :param ef_horizon: Ego-Foresight prediction horizon H (the rollout length k is drawn in [1, H]).
    :param babbling_steps: steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` (random +-1) or ``"clamped_uniform"``.
    :param babbling_in_eval: ``predict`` also babbles during the babbling steps (the EF authors' Meta-World protocol).
    :param policy_kwargs: see :class:`TDMPC2EFPolicy`.
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
        super().__init__(**base_arguments(TDMPC2, locals(), _init_setup_model=False))
        ef_kwargs = self.policy_kwargs.get("ef_kwargs")
        self._init_ef(beta, ef_horizon, babbling_steps, babbling_mode, babbling_in_eval, ef_kwargs)
        if _init_setup_model:
            self._setup_model()

    def _build_auxiliary(self) -> ForesightLoss:
        """EF on the world model's encoder, fed ``obs / 255 - 0.5`` as :meth:`WorldModel.encode` feeds it."""
        policy = self._ef_policy()
        model = policy.world_model
        return self._foresight_loss(
            model.encoder, model.latent_dim, policy.agent_dim, policy.ef_kwargs, policy.channels_last, encode_frames
        )
