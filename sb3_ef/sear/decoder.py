"""SEAR's decoder: half of the latent back to a full-size image through the transpose of the pooled DrQ-v2 encoder
(the authors' ``PoolDecoder`` at 84x84; other sizes get the output paddings that invert the encoder's)."""

from __future__ import annotations

import itertools

import torch as th
from torch import nn

from sb3_ef.common.layers import orthogonal_init

# Channels of the decoder's first map and of its hidden transposed convolutions (the authors' values).
_IN_CHANNELS = 16
_HIDDEN = (16, 32, 32, 32)
_POOL = 4
_STRIDE_ONE_LAYERS = 3  # 3x3 stride-1 convolutions after the encoder's first (stride-2) one

#: Smallest frame side the pooled DrQ-v2 encoder (and so this decoder) handles: a 1x1 pooled map.
MIN_FRAME_SIZE = 21


def _encoder_sizes(size: int) -> tuple[int, int]:
    """(conv output size, pooled size) of the pooled DrQ-v2 encoder along one image axis."""
    conv = (size - 3) // 2 + 1 - 2 * _STRIDE_ONE_LAYERS
    return conv, conv // _POOL


class SEARDecoder(nn.Module):
    """Linear + ReLU to a pooled map, then transposed convolutions to a full-size image, with no output activation.

    :param in_dim: size of the latent half the decoder reads.
    :param out_channels: channels of the decoded image (3 x frame stack for frames, frame stack for masks).
    :param height: frame height (at least :data:`MIN_FRAME_SIZE`).
    :param width: frame width (at least :data:`MIN_FRAME_SIZE`).
    """

    def __init__(self, in_dim: int, out_channels: int, height: int, width: int):
        super().__init__()
        if min(height, width) < MIN_FRAME_SIZE:
            raise ValueError(
                f"SEAR's decoder needs frames of at least {MIN_FRAME_SIZE}x{MIN_FRAME_SIZE} (a 1x1 pooled encoder "
                f"map), got {height}x{width}"
            )
        (conv_h, pooled_h), (conv_w, pooled_w) = _encoder_sizes(height), _encoder_sizes(width)
        self.pooled_shape = (_IN_CHANNELS, pooled_h, pooled_w)
        self.projection = nn.Sequential(nn.Linear(in_dim, _IN_CHANNELS * pooled_h * pooled_w), nn.ReLU())
        first_conv = (conv_h + 2 * _STRIDE_ONE_LAYERS, conv_w + 2 * _STRIDE_ONE_LAYERS)
        layers: list[nn.Module] = [
            nn.ConvTranspose2d(
                _IN_CHANNELS,
                _HIDDEN[0],
                _POOL,
                stride=_POOL,
                output_padding=(conv_h - _POOL * pooled_h, conv_w - _POOL * pooled_w),
            ),
            nn.ReLU(),
        ]
        for in_channels, out in itertools.pairwise(_HIDDEN):
            layers += [nn.ConvTranspose2d(in_channels, out, 3, stride=1), nn.ReLU()]
        layers.append(
            nn.ConvTranspose2d(
                _HIDDEN[-1],
                out_channels,
                3,
                stride=2,
                output_padding=(height - 2 * first_conv[0] - 1, width - 2 * first_conv[1] - 1),
            )
        )
        self.deconvs = nn.Sequential(*layers)
        self.apply(orthogonal_init)

    def forward(self, latent: th.Tensor) -> th.Tensor:
        return self.deconvs(self.projection(latent).view(-1, *self.pooled_shape))
