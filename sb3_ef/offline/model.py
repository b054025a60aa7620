"""``OfflineEF``: an encoder and an ``EgoForesight`` trained together on video, saved with their configuration."""

from __future__ import annotations

import os
import pickle
import zipfile
from dataclasses import asdict, dataclass, field
from typing import Any

import torch as th
from torch import nn

from sb3_ef.ef.arguments import check_ef_kwargs
from sb3_ef.ef.foresight import LatentEgoForesight, ego_foresight
from sb3_ef.ef.latent import DEFAULT_TARGET_TAU, MomentumTarget
from sb3_ef.offline.encoders import build_encoder


@dataclass
class OfflineEFConfig:
    """Everything needed to rebuild an :class:`OfflineEF` (stored in every checkpoint)."""

    encoder: str
    frame_shape: tuple[int, int, int]
    action_dim: int
    context: int = 3
    horizon: int = 10
    agent_dim: int = 32
    encoder_kwargs: dict[str, Any] = field(default_factory=dict)
    ef_kwargs: dict[str, Any] = field(default_factory=dict)


class OfflineEF(nn.Module):
    """Encoder + Ego-Foresight; ``features(obs)`` gives ``(h, skip)`` for uint8 stacked context frames, oldest first."""

    def __init__(self, config: OfflineEFConfig):
        super().__init__()
        if config.context < 1:
            raise ValueError(f"context must be at least 1 frame, got {config.context}")
        check_ef_kwargs(config.ef_kwargs)
        self.config = config
        self.encoder = build_encoder(
            config.encoder, config.frame_shape, config.context, config.action_dim, **dict(config.encoder_kwargs)
        )
        options = dict(config.ef_kwargs)
        target_tau = options.pop("target_tau", None)
        if target_tau is not None and options.get("target", "pixel") != "latent":
            raise ValueError("ef_kwargs target_tau applies to target='latent' only, got it with target='pixel'")
        self.ef = ego_foresight(
            self.encoder.features_dim,
            config.action_dim,
            frame_shape=self.frame_shape,
            agent_dim=config.agent_dim,
            horizon=config.horizon,
            skip_channels=self.encoder.skip_channels,
            **options,
        )
        # Latent EF (ef_kwargs target="latent"): the momentum copy of the encoder whose features it predicts.
        self.target_encoder = (
            MomentumTarget(self.encoder, self.ef.head.projection, target_tau or DEFAULT_TARGET_TAU)
            if isinstance(self.ef, LatentEgoForesight)
            else None
        )

    def features(self, observations: th.Tensor) -> tuple[th.Tensor, th.Tensor | None]:
        return self.encoder(observations)

    def encode(self, observations: th.Tensor) -> th.Tensor:
        """Features h only (the contract of RL models' ``encode``)."""
        return self.encoder(observations)[0]

    @property
    def frame_shape(self) -> tuple[int, int, int]:
        return tuple(self.config.frame_shape)  # type: ignore[return-value]

    def checkpoint(self, **extra: Any) -> dict[str, Any]:
        """A dict for ``th.save``: configuration, weights and ``extra`` (step, optimiser, ...)."""
        return {"config": asdict(self.config), "state_dict": self.state_dict(), **extra}


def read_checkpoint(path: str | os.PathLike, device: str | th.device = "cpu") -> dict[str, Any]:
    """The dict of a ``pretrain`` checkpoint, unpickled ``weights_only``; any other file is a ``ValueError``."""
    name = os.fspath(path)
    if not os.path.isfile(name):
        raise FileNotFoundError(f"No pretrained model at {name!r}")
    if zipfile.is_zipfile(name) and _is_sb3_zip(name):
        raise ValueError(
            f"{name!r} is a Stable-Baselines3 model zip (an RL agent, as sb3-ef train saves it), not a model of sb3-ef "
            "pretrain: pass the OUT/model.pt or OUT/checkpoint.pt it wrote (for an RL agent: sb3-ef analyze model)"
        )
    try:
        checkpoint = th.load(name, map_location=device, weights_only=True)
    except (RuntimeError, EOFError, OSError, ValueError, pickle.UnpicklingError) as error:
        reason = " ".join(str(error).split()).split(". ")[0] or type(error).__name__  # torch adds advice after it
        reason = "an empty file" if os.path.getsize(name) == 0 else reason
        raise ValueError(
            f"{name!r} is not a readable checkpoint of sb3-ef pretrain (damaged, truncated or another file: {reason})"
        ) from None
    if not isinstance(checkpoint, dict) or "config" not in checkpoint or "state_dict" not in checkpoint:
        raise ValueError(f"{name!r} is not an sb3-ef offline checkpoint (no 'config' / 'state_dict')")
    return checkpoint


def load_pretrained(path: str | os.PathLike, device: str | th.device = "cpu") -> tuple[OfflineEF, dict[str, Any]]:
    """The :class:`OfflineEF` of a ``pretrain`` checkpoint (in eval mode) and the checkpoint's dict."""
    checkpoint = read_checkpoint(path, device)
    config = dict(checkpoint["config"])
    config["frame_shape"] = tuple(config["frame_shape"])
    model = OfflineEF(OfflineEFConfig(**config)).to(device)
    try:
        model.load_state_dict(checkpoint["state_dict"])
    except RuntimeError as error:
        raise ValueError(f"{os.fspath(path)!r}: its weights do not fit its configuration ({error})") from None
    return model.eval(), checkpoint


def _is_sb3_zip(path: str) -> bool:
    """Stable-Baselines3 saves a zip holding ``data`` (JSON) beside ``policy.pth``; torch's archives have none."""
    with zipfile.ZipFile(path) as archive:
        return "data" in archive.namelist()
