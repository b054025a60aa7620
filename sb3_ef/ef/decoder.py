"""DCGAN-style frame decoder: a feature vector, seen as a 1x1 image, up-sampled to one frame."""

from __future__ import annotations

import math
from typing import cast

import torch as th
from torch import nn
from torch.nn import functional as F

# (kernel, stride, padding) of each transposed convolution; 84x84 follows the authors' stack: 1->5->10->21->42->84.
_LAYERS_84 = ((5, 1, 0), (4, 2, 1), (5, 2, 1), (4, 2, 1), (4, 2, 1))
SUPPORTED_SIZES_TEXT = "84 or 4 * 2**n with n >= 1 (8, 16, 32, 64, 128, ...)"


def decoder_layers(size: int) -> tuple[tuple[int, int, int], ...]:
    """The (kernel, stride, padding) of each layer from 1x1 to ``size`` x ``size``."""
    if size == 84:
        return _LAYERS_84
    doublings = math.log2(size / 4) if size >= 8 else 0.0
    if size >= 8 and doublings == int(doublings):
        return ((4, 1, 0),) + ((4, 2, 1),) * int(doublings)
    raise ValueError(f"Unsupported frame size {size}: the decoder supports square frames of {SUPPORTED_SIZES_TEXT}")


class FrameDecoder(nn.Module):
    """DCGAN-style transposed convolutions to a frame in [0, 1], with optional U-Net skips of an encoder map.

    :param in_dim: size of the input feature vector.
    :param frame_shape: (channels, size, size) of the decoded frame.
    :param channels: width of every hidden layer.
    :param skip_channels: channels of the skip feature map, 0 for none.
    """

    def __init__(self, in_dim: int, frame_shape: tuple[int, int, int], channels: int = 64, skip_channels: int = 0):
        super().__init__()
        if len(frame_shape) != 3 or frame_shape[1] != frame_shape[2]:
            raise ValueError(f"Expected a square frame shape (channels, size, size), got {tuple(frame_shape)}")
        if channels < 1 or skip_channels < 0:
            raise ValueError(f"Expected channels >= 1 and skip_channels >= 0, got {channels} and {skip_channels}")
        self.frame_shape = tuple(frame_shape)
        self.skip_channels = skip_channels
        layers = decoder_layers(frame_shape[1])
        blocks = []
        self.input_sizes: list[int] = []
        size = 1
        for index, (kernel, stride, padding) in enumerate(layers):
            last = index == len(layers) - 1
            in_channels = in_dim if index == 0 else channels + skip_channels
            out_channels = frame_shape[0] if last else channels
            conv = nn.ConvTranspose2d(in_channels, out_channels, kernel, stride, padding, bias=False)
            tail = [nn.Sigmoid()] if last else [nn.BatchNorm2d(out_channels), nn.LeakyReLU(0.2)]
            blocks.append(nn.Sequential(conv, *tail))
            self.input_sizes.append(size)
            size = (size - 1) * stride - 2 * padding + kernel  # a transposed convolution's output size
        self.blocks = nn.ModuleList(blocks)
        self.apply(_dcgan_init)

    def forward(self, features: th.Tensor, skip: th.Tensor | None = None) -> th.Tensor:
        """Decode (B, in_dim) features (and the skip map if skips are on) to (B, C, h, w)."""
        if (skip is None) != (self.skip_channels == 0):
            raise ValueError(
                f"This decoder has skip_channels={self.skip_channels}: "
                f"{'pass' if self.skip_channels else 'do not pass'} a skip feature map"
            )
        if skip is not None and (skip.dim() != 4 or skip.shape[:2] != (features.shape[0], self.skip_channels)):
            raise ValueError(
                f"Expected a skip map of shape ({features.shape[0]}, {self.skip_channels}, h, w), "
                f"got {tuple(skip.shape)}"
            )
        # On a 1x1 input the first transposed convolution is a matmul: computed as one (several times faster on CPU).
        first_conv, *first_tail = cast(nn.Sequential, self.blocks[0])
        weight = cast(nn.ConvTranspose2d, first_conv).weight
        x = (features @ weight.flatten(1)).unflatten(1, weight.shape[1:])
        for layer in first_tail:
            x = layer(x)
        for index, block in enumerate(self.blocks[1:], start=1):
            if skip is not None:
                size = self.input_sizes[index]
                x = th.cat([x, F.interpolate(skip, size=(size, size), mode="bilinear", align_corners=False)], dim=1)
            x = block(x)
        return x


def _dcgan_init(module: nn.Module) -> None:
    """DCGAN initialisation: conv weights N(0, 0.02), BatchNorm scales N(1, 0.02) and shifts 0."""
    if isinstance(module, nn.ConvTranspose2d):
        nn.init.normal_(module.weight, 0.0, 0.02)
    elif isinstance(module, nn.BatchNorm2d):
        nn.init.normal_(module.weight, 1.0, 0.02)
        nn.init.zeros_(module.bias)
