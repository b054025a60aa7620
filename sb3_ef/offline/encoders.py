"""Image encoders for offline EF (DrQ-v2's, TD-MPC2's, the BAIR DCGAN U-Net), each returning ``(h, skip)``."""

from __future__ import annotations

import numpy as np
import torch as th
from gymnasium import spaces
from torch import nn

from sb3_ef.common.env_checks import FRAME_CHANNELS
from sb3_ef.common.validation import check_keyword_arguments
from sb3_ef.drqv2.policies import DrQv2Encoder
from sb3_ef.tdmpc2.world_model import FRAME_SIZE, WorldModel

ENCODERS = ("dcgan-unet", "drqv2", "tdmpc2")
DCGAN_FRAME_SIZE = 64


class DCGANUNetEncoder(nn.Module):
    """The BAIR model's DCGAN encoder for 64x64 frames; block ``skip_block`` gives the U-Net skip (scene detail)."""

    def __init__(self, in_channels: int, features_dim: int = 128, width: int = 32, skip_block: int | None = 1):
        super().__init__()
        if skip_block is not None and not 0 <= skip_block < 4:
            raise ValueError(f"skip_block must be None or in [0, 3], got {skip_block}")
        blocks = []
        channels = in_channels
        for index in range(4):
            out = width * 2**index
            norm: nn.Module = nn.BatchNorm2d(out) if index > 0 else nn.Identity()
            blocks.append(nn.Sequential(nn.Conv2d(channels, out, 4, 2, 1, bias=False), norm, nn.LeakyReLU(0.2)))
            channels = out
        self.blocks = nn.ModuleList(blocks)
        self.head = nn.Sequential(nn.Conv2d(channels, features_dim, 4, 1, 0), nn.Flatten(), nn.Tanh())
        self.skip_block = skip_block
        self.skip_channels = 0 if skip_block is None else width * 2**skip_block
        self.features_dim = features_dim

    def forward(self, observations: th.Tensor) -> tuple[th.Tensor, th.Tensor | None]:
        x = observations.float() / 255.0 - 0.5
        skip = None
        for index, block in enumerate(self.blocks):
            x = block(x)
            if index == self.skip_block:
                skip = x
        return self.head(x), skip


class HostEncoder(nn.Module):
    """A host's encoder as ``net`` (state-dict compatible with the host's), returning ``(h, None)``."""

    def __init__(self, net: nn.Module, features_dim: int, encode_scaled: bool):
        super().__init__()
        self.net = net
        self.features_dim = features_dim
        self.skip_channels = 0
        self._scale = encode_scaled  # the TD-MPC2 Sequential expects frames already scaled to [-0.5, 0.5]

    def forward(self, observations: th.Tensor) -> tuple[th.Tensor, None]:
        if self._scale:
            return self.net(observations.float() / 255.0 - 0.5), None
        return self.net(observations), None


#: What each encoder's ``kwargs`` go to, and the arguments :func:`build_encoder` sets itself.
_KWARGS_TARGETS: dict[str, tuple[type, tuple[str, ...]]] = {
    "dcgan-unet": (DCGANUNetEncoder, ("in_channels",)),
    "drqv2": (DrQv2Encoder, ("observation_space",)),
    "tdmpc2": (WorldModel, ("in_channels", "action_dim", "mlp_dim", "num_q")),
}


def build_encoder(
    kind: str, frame_shape: tuple[int, int, int], context: int, action_dim: int, **kwargs
) -> DCGANUNetEncoder | HostEncoder:
    """The encoder ``kind`` (one of :data:`ENCODERS`) for ``context`` stacked frames of ``frame_shape``."""
    if kind in _KWARGS_TARGETS:
        target, set_here = _KWARGS_TARGETS[kind]
        check_keyword_arguments(f"the {kind} encoder's encoder_kwargs (--encoder-kwargs)", target, kwargs, set_here)
    _, height, width = frame_shape
    in_channels = FRAME_CHANNELS * context
    if kind == "dcgan-unet":
        if (height, width) != (DCGAN_FRAME_SIZE, DCGAN_FRAME_SIZE):
            raise ValueError(f"The dcgan-unet encoder takes 64x64 frames, got {height}x{width}")
        return DCGANUNetEncoder(in_channels, **kwargs)
    if kind == "drqv2":
        space = spaces.Box(0, 255, (in_channels, height, width), dtype=np.uint8)
        net = DrQv2Encoder(space, features_dim=kwargs.pop("features_dim", 2048), **kwargs)
        return HostEncoder(net, net.features_dim, encode_scaled=False)
    if kind == "tdmpc2":
        if (height, width) != (FRAME_SIZE, FRAME_SIZE):
            raise ValueError(f"The tdmpc2 encoder takes {FRAME_SIZE}x{FRAME_SIZE} frames, got {height}x{width}")
        # The encoder is built inside TD-MPC2's world model; the smallest heads keep the rest of it cheap.
        world_model = WorldModel(in_channels, action_dim, mlp_dim=1, num_q=2, **kwargs)
        return HostEncoder(world_model.encoder, world_model.latent_dim, encode_scaled=True)
    raise ValueError(f"Unknown encoder {kind!r}, expected one of {ENCODERS}")
