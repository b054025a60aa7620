"""CURL's pixel encoder as an SB3 features extractor: SAC-AE's conv stack, a linear layer and LayerNorm."""

from __future__ import annotations

import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn

from sb3_ef.common.augmentation import center_crop
from sb3_ef.common.env_checks import check_stacked_frames


def _conv_output_size(size: int, n_layers: int) -> int:
    """Side of the last conv map: one 3x3 stride-2 convolution, then ``n_layers - 1`` 3x3 stride-1 ones."""
    return (size - 3) // 2 + 1 - 2 * (n_layers - 1)


def weight_init(module: nn.Module) -> None:
    """The authors' ``weight_init`` (for ``module.apply``): orthogonal linear, delta-orthogonal conv, zero biases."""
    if isinstance(module, nn.Linear):
        nn.init.orthogonal_(module.weight)
        nn.init.zeros_(module.bias)
    elif isinstance(module, nn.Conv2d):
        nn.init.zeros_(module.weight)
        if module.bias is not None:
            nn.init.zeros_(module.bias)
        centre = module.kernel_size[0] // 2
        with th.no_grad():
            nn.init.orthogonal_(module.weight[:, :, centre, centre], nn.init.calculate_gain("relu"))


class CURLEncoder(BaseFeaturesExtractor):
    """CURL's encoder (docs/curl.md, "Networks"); it centre-crops larger inputs and scales images itself.

    :param observation_space: uint8 Box of stacked frames (3 * frame_stack, height, width).
    :param features_dim: size of the features (CURL's ``encoder_feature_dim``).
    :param crop_size: side of the images the encoder sees; ``None`` for the whole frame (square frames only).
    :param n_layers: number of convolutions.
    :param n_filters: channels of every convolution.
    """

    def __init__(
        self,
        observation_space: spaces.Box,
        features_dim: int = 50,
        crop_size: int | None = None,
        n_layers: int = 4,
        n_filters: int = 32,
    ):
        channels, height, width = check_stacked_frames(observation_space, "CURL")
        if crop_size is None and height != width:
            raise ValueError(f"CURL's encoder needs square images: give crop_size for {height}x{width} frames")
        crop_size = height if crop_size is None else crop_size
        if isinstance(crop_size, bool) or not isinstance(crop_size, int) or not 1 <= crop_size <= min(height, width):
            raise ValueError(
                f"crop_size must be an int in [1, {min(height, width)}] (at most the {height}x{width} frames), "
                f"got {crop_size!r}"
            )
        for name, value in (("features_dim", features_dim), ("n_layers", n_layers), ("n_filters", n_filters)):
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"{name} must be a positive int, got {value!r}")
        conv_size = _conv_output_size(crop_size, n_layers)
        if conv_size < 1:
            raise ValueError(f"Crops of {crop_size}x{crop_size} are too small for {n_layers} convolutions")
        super().__init__(observation_space, features_dim)
        self.crop_size = crop_size
        layers: list[nn.Module] = []
        for index in range(n_layers):
            layers += [nn.Conv2d(channels if index == 0 else n_filters, n_filters, 3, stride=2 if index == 0 else 1)]
            layers.append(nn.ReLU())
        self.convnet = nn.Sequential(*layers, nn.Flatten())
        self.projection = nn.Sequential(nn.Linear(n_filters * conv_size**2, features_dim), nn.LayerNorm(features_dim))
        self.apply(weight_init)
        self.detach_convolutions = False

    def share_convolutions(self, source: CURLEncoder) -> None:
        """Tie to ``source``'s convolutions, detached here, as the authors' actor encoder."""
        if not isinstance(source, CURLEncoder) or source.crop_size != self.crop_size:
            raise ValueError(f"CURLEncoder shares the convolutions of a CURLEncoder of the same crop, got {source!r}")
        if [p.shape for p in source.convnet.parameters()] != [p.shape for p in self.convnet.parameters()]:
            raise ValueError("CURLEncoder shares the convolutions of an encoder with the same layers and filters")
        self.convnet = source.convnet
        self.detach_convolutions = True

    def forward(self, observations: th.Tensor) -> th.Tensor:
        if observations.shape[-2:] != (self.crop_size, self.crop_size):
            observations = center_crop(observations, self.crop_size)
        hidden = self.convnet(observations.float() / 255.0)
        return self.projection(hidden.detach() if self.detach_convolutions else hidden)
