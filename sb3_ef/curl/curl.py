"""CURL: SB3's SAC from pixels with CURL's contrastive loss on the critic's encoder (Laskin et al., 2020)."""

from __future__ import annotations

from typing import Any

import torch as th
from stable_baselines3 import SAC
from stable_baselines3.common.type_aliases import GymEnv

from sb3_ef.auxiliary.step import AuxiliaryStepMixin
from sb3_ef.curl.buffer import CroppedSequenceReplayBuffer
from sb3_ef.curl.encoder import CURLEncoder
from sb3_ef.curl.loss import CURLLoss


class CroppedHostUpdates:
    """Mixed in between :class:`AuxiliaryStepMixin` and the host: the host's own updates sample random crops from
    the :class:`CroppedSequenceReplayBuffer` (its ``cropping`` block), the auxiliary steps after them whole frames."""

    replay_buffer: CroppedSequenceReplayBuffer

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        with self.replay_buffer.cropping():
            super().train(gradient_steps, batch_size)  # type: ignore[misc]


class CURL(AuxiliaryStepMixin, CroppedHostUpdates, SAC):
    """CURL (Laskin, Srinivas and Abbeel, "CURL: Contrastive Unsupervised Representations for Reinforcement
    Learning", ICML 2020): SB3's SAC whose critic and actor encode random ``crop_size`` crops of the rendered frames
    with :class:`CURLEncoder` (acting on the centre crop), and whose critic's encoder is also trained by CURL's
    contrastive loss (:class:`CURLLoss`: InfoNCE between two crops, a bilinear W and a momentum key encoder), as a
    step of its own after each SAC update (:class:`AuxiliaryStepMixin`).

    CURL's arguments are keyword-only, as :class:`AuxiliaryStepMixin`'s (``auxiliary_learning_rate``: W's and the
    encoder's rate in the CURL step, the host's ``learning_rate`` by default; ``check_finite_losses``; its
    ``shift_pad`` is not used, CURL's augmentation is the crop); every other argument is SAC's. The key encoder
    moves every ``target_update_interval`` CURL steps, as the authors move it with the critic target.

    :param crop_size: side of the random crops the encoders see (84 of the paper's 100x100 renders), at most the
        frame size.
    :param encoder_tau: momentum of the key encoder, ``key <- (1 - tau) key + tau online`` (0.05).
    :param features_dim: size of :class:`CURLEncoder`'s features (50); ``policy_kwargs["features_extractor_kwargs"]``
        sets its other options (``n_layers``, ``n_filters``).
    """

    replay_buffer: CroppedSequenceReplayBuffer

    def __init__(
        self,
        policy: Any,
        env: GymEnv | str | None,
        *,
        crop_size: int = 84,
        encoder_tau: float = 0.05,
        features_dim: int = 50,
        _init_setup_model: bool = True,
        **kwargs: Any,
    ):
        policy_kwargs = dict(kwargs.pop("policy_kwargs", None) or {})
        extractor = policy_kwargs.setdefault("features_extractor_class", CURLEncoder)
        if not (isinstance(extractor, type) and issubclass(extractor, CURLEncoder)):
            raise ValueError(f"CURL's features extractor must be a CURLEncoder (sub)class, got {extractor!r}")
        if policy_kwargs.setdefault("normalize_images", False):
            raise ValueError("CURLEncoder scales the images itself: CURL needs policy_kwargs normalize_images=False")
        policy_kwargs["features_extractor_kwargs"] = {
            "features_dim": features_dim,
            **policy_kwargs.get("features_extractor_kwargs", {}),
            "crop_size": crop_size,
        }
        super().__init__(policy, env, policy_kwargs=policy_kwargs, _init_setup_model=False, **kwargs)
        self.crop_size = crop_size
        self.encoder_tau = encoder_tau
        self.features_dim = features_dim
        if _init_setup_model:
            self._setup_model()

    def _setup_model(self) -> None:
        """Check the crop against the frames (here, so that ``load`` checks the saved values), then a
        :class:`CroppedSequenceReplayBuffer` of ``crop_size`` crops and the host's setup."""
        _, height, width = self.observation_space.shape  # type: ignore[misc]
        crop_size = self.crop_size
        if isinstance(crop_size, bool) or not isinstance(crop_size, int) or not 1 <= crop_size <= min(height, width):
            raise ValueError(
                f"CURL's crop_size must be an int in [1, {min(height, width)}] (at most the {height}x{width} frames: "
                f"render larger frames, e.g. make_env(..., size=100) for crops of 84), got {crop_size!r}"
            )
        if not 0.0 < self.encoder_tau <= 1.0:
            raise ValueError(f"encoder_tau must be in (0, 1], got {self.encoder_tau!r}")
        if self.replay_buffer_class is None:
            self.replay_buffer_class = CroppedSequenceReplayBuffer
        elif not issubclass(self.replay_buffer_class, CroppedSequenceReplayBuffer):
            raise ValueError(
                "CURL's SAC updates sample random crops: replay_buffer_class must be a CroppedSequenceReplayBuffer "
                f"(or None), got {self.replay_buffer_class.__name__}"
            )
        self.replay_buffer_kwargs = {**self.replay_buffer_kwargs, "crop_size": self.crop_size}
        super()._setup_model()

    def _build_auxiliary(self) -> CURLLoss:
        """CURL's loss on the critic's encoder, built from a fork of the global generator (W's initial draw) so that
        SAC's own random draws are those it has without CURL."""
        with th.random.fork_rng(devices=[]):
            return CURLLoss(
                self.critic.features_extractor,
                self.crop_size,
                self.encoder_tau,
                key_update_interval=self.target_update_interval,
            )
