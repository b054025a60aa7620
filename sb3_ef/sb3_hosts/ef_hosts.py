"""SAC-EF, TD3-EF and TQC-EF: SB3's algorithms, unchanged, plus Ego-Foresight trained on the critic's encoder.

SB3's ``train()`` has no hook for an extra loss, so EF runs as its own step after each of the host's updates, as
CURL's reference trains its auxiliary loss: sample a window, shift the context and frame t+k together, encode with
the critic's features extractor and take one step of a separate Adam on that extractor and the EF module. The
host's updates, losses and optimisers are SB3's own (see docs/ef.md for the choice).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from sb3_contrib import TQC
from stable_baselines3 import SAC, TD3
from stable_baselines3.common.base_class import maybe_make_env
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.type_aliases import GymEnv

from sb3_ef.common.buffers import SequenceReplayBufferSamples
from sb3_ef.common.env_checks import check_box_actions, check_stacked_frames, episode_steps
from sb3_ef.common.validation import check_algorithm_arguments
from sb3_ef.ef.host import EFHostMixin, build_ef, check_horizon_fits_episodes
from sb3_ef.sb3_hosts.shifted_buffer import ShiftedSequenceReplayBuffer


class AuxiliaryEFMixin(EFHostMixin):
    """Adds Ego-Foresight to an SB3 off-policy algorithm whose critic has a ``features_extractor`` (a CNN on stacked
    RGB frames): ``class SACEF(AuxiliaryEFMixin, SAC)``.

    EF's arguments are keyword-only; every other argument is the host's own and goes to it unchanged.

    :param beta: weight of the EF loss in its step. EF's optimiser is its own Adam, which normalises the gradient's
        scale, so ``beta`` barely changes the step: ``ef_learning_rate`` sets how strongly EF moves the encoder.
    :param ef_horizon: EF's prediction horizon H (the rollout length k is drawn in [1, H]).
    :param agent_dim: size of the agent features, the first ``agent_dim`` features of the critic's encoder.
    :param ef_kwargs: extra arguments of :class:`sb3_ef.ef.EgoForesight` (decoder / rollout options).
    :param shift_pad: random shift (pixels) applied to the context and frame t+k of EF's step; 0 for none. With a
        :class:`ShiftedSequenceReplayBuffer` (``replay_buffer_class``), which shifts every batch of the host and of
        EF itself, EF's step adds no shift of its own.
    :param ef_learning_rate: learning rate of EF's optimiser; ``None`` uses the host's ``learning_rate`` (schedule).
    :param babbling_steps: steps of motor babbling at the start (0: none).
    :param babbling_mode: ``"sign"`` (random +-1) or ``"clamped_uniform"``.
    :param babbling_in_eval: ``predict`` also babbles while ``num_timesteps < babbling_steps``.
    :param check_finite_losses: raise a ``ValueError`` when EF's loss is NaN or infinite, before its optimiser step
        (the host's own losses are computed inside SB3's ``train()`` and are not checked).
    """

    policy: Any
    critic: Any
    ef_optimizer: th.optim.Optimizer

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        *,
        beta: float = 1.0,
        ef_horizon: int = 10,
        agent_dim: int = 32,
        ef_kwargs: dict[str, Any] | None = None,
        shift_pad: int = 4,
        ef_learning_rate: float | None = None,
        babbling_steps: int = 0,
        babbling_mode: str = "sign",
        babbling_in_eval: bool = False,
        check_finite_losses: bool = False,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        check_algorithm_arguments(type(self), locals())
        host = next(
            c for c in type(self).__mro__ if issubclass(c, OffPolicyAlgorithm) and not issubclass(c, EFHostMixin)
        )
        if env is not None:
            env = maybe_make_env(env, kwargs.get("verbose", 0))
            check_stacked_frames(env.observation_space, type(self).__name__)
            check_box_actions(env.action_space, type(self).__name__)
        for name in ("policy_kwargs", "replay_buffer_kwargs"):
            kwargs[name] = dict(kwargs.get(name) or {})
        super().__init__(policy, env, _init_setup_model=False, **kwargs)  # type: ignore[call-arg]
        self._init_ef(
            beta, ef_horizon, babbling_steps, babbling_mode, babbling_in_eval, check_finite_losses, host.__name__
        )
        if shift_pad < 0:
            raise ValueError(f"shift_pad must be >= 0, got {shift_pad}")
        self.agent_dim = agent_dim
        self.ef_kwargs = dict(ef_kwargs or {})
        self.shift_pad = shift_pad
        self.ef_learning_rate = ef_learning_rate
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """The host's setup with a sequence replay buffer, then the EF module (on the policy, so that it is saved
        with it) and EF's optimiser over EF and the critic's features extractor."""
        if self.env is not None:
            check_horizon_fits_episodes(self.ef_horizon, episode_steps(self.env))
        self._use_sequence_buffer(
            f"{type(self).__name__} samples Ego-Foresight windows",
            horizon=self.ef_horizon or 1,
            n_steps=self.n_steps,  # type: ignore[attr-defined]
            gamma=self.gamma,  # type: ignore[attr-defined]
        )
        super()._setup_model()
        encoder = self.critic.features_extractor
        # Built from a fork of the global generator, so that the host's own random draws are those it has without EF.
        with th.random.fork_rng(devices=[]):
            ef = build_ef(
                encoder.features_dim,
                int(np.prod(self.action_space.shape)),  # type: ignore[arg-type]
                self.frame_shape,
                self.agent_dim,
                self.ef_horizon,
                self.ef_kwargs,
                channels_last=False,
            )
        self.policy.ef = None if ef is None else ef.to(self.device)
        if ef is not None:
            learning_rate = self.ef_learning_rate or self.lr_schedule(1)  # type: ignore[attr-defined]
            self.ef_optimizer = th.optim.Adam([*ef.parameters(), *encoder.parameters()], lr=learning_rate)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h of the critic's encoder for uint8 stacked observations (no augmentation)."""
        return self.critic.extract_features(observations.to(self.device), self.critic.features_extractor)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        """The host's ``gradient_steps`` updates, unchanged, then as many EF steps (:meth:`_update_ef`)."""
        super().train(gradient_steps, batch_size)  # type: ignore[misc]
        if self.ef is None:
            return
        if self.ef_learning_rate is None:
            self._update_learning_rate(self.ef_optimizer)  # type: ignore[attr-defined]
        self.ef.train(True)
        updates = [
            self._update_ef(self.replay_buffer.sample(batch_size, env=self._vec_normalize_env))  # type: ignore[attr-defined]
            for _ in range(gradient_steps)
        ]
        self._record_updates(updates)

    def _update_ef(self, batch: SequenceReplayBufferSamples) -> dict[str, th.Tensor]:
        """One EF step on the critic's encoder and the EF module; returns the (detached) loss, without a sync."""
        pad = 0 if isinstance(self.replay_buffer, ShiftedSequenceReplayBuffer) else self.shift_pad
        observations, window = self._ef_window(batch, pad=pad)
        ef_loss = self._ef_loss(self.encode(observations), batch.future_actions, window)
        assert ef_loss is not None and self.beta is not None
        self._check_finite(ef_loss=ef_loss)
        self.ef_optimizer.zero_grad()
        (self.beta * ef_loss).backward()
        self.ef_optimizer.step()
        return {"ef_loss": ef_loss.detach()}

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        state_dicts, variables = super()._get_torch_save_params()  # type: ignore[misc]
        return ([*state_dicts, "ef_optimizer"] if self.ef is not None else state_dicts), variables


class SACEF(AuxiliaryEFMixin, SAC):
    """SAC (Haarnoja et al., 2018) from pixels with Ego-Foresight on the critic's encoder. Takes SAC's arguments
    and EF's (keyword-only, see :class:`AuxiliaryEFMixin`); the env must give stacked uint8 RGB frames."""


class TD3EF(AuxiliaryEFMixin, TD3):
    """TD3 (Fujimoto et al., 2018) from pixels with Ego-Foresight on the critic's encoder. Takes TD3's arguments
    and EF's (keyword-only, see :class:`AuxiliaryEFMixin`); the env must give stacked uint8 RGB frames."""


class TQCEF(AuxiliaryEFMixin, TQC):
    """TQC (Kuznetsov et al., 2020, sb3-contrib) from pixels with Ego-Foresight on the critic's encoder. Takes TQC's
    arguments and EF's (keyword-only, see :class:`AuxiliaryEFMixin`); the env must give stacked uint8 RGB frames."""
