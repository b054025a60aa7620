"""``OfflineEF``: an encoder and an ``EgoForesight`` trained together on video, saved with their configuration."""

from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from typing import Any

import torch as th
from torch import nn

from sb3_ef.ef import EgoForesight
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
    """Encoder + Ego-Foresight. ``features(obs)`` gives ``(h, skip)`` for uint8 stacked context frames
    (B, 3 * context, H, W), oldest first, as sb3-ef envs stack them."""

    def __init__(self, config: OfflineEFConfig):
        super().__init__()
        if config.context < 1:
            raise ValueError(f"context must be at least 1 frame, got {config.context}")
        self.config = config
        self.encoder = build_encoder(
            config.encoder, config.frame_shape, config.context, config.action_dim, **dict(config.encoder_kwargs)
        )
        self.ef = EgoForesight(
            self.encoder.features_dim,
            config.action_dim,
            frame_shape=self.frame_shape,
            agent_dim=config.agent_dim,
            horizon=config.horizon,
            skip_channels=self.encoder.skip_channels,
            **config.ef_kwargs,
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


def load_pretrained(path: str | os.PathLike, device: str | th.device = "cpu") -> tuple[OfflineEF, dict[str, Any]]:
    """Rebuild an :class:`OfflineEF` from a checkpoint written by ``pretrain``; returns it (in eval mode) and the
    whole checkpoint dict."""
    if not os.path.isfile(path):
        raise FileNotFoundError(f"No pretrained model at {os.fspath(path)!r}")
    checkpoint = th.load(path, map_location=device, weights_only=False)
    if not isinstance(checkpoint, dict) or "config" not in checkpoint or "state_dict" not in checkpoint:
        raise ValueError(f"{os.fspath(path)!r} is not an sb3-ef offline checkpoint (no 'config' / 'state_dict')")
    config = dict(checkpoint["config"])
    config["frame_shape"] = tuple(config["frame_shape"])
    model = OfflineEF(OfflineEFConfig(**config)).to(device)
    model.load_state_dict(checkpoint["state_dict"])
    return model.eval(), checkpoint
