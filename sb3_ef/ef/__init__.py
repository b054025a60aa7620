"""Ego-Foresight: agent/scene split, action-conditioned rollout, frame decoder and loss (algorithm-agnostic), and the
auxiliary-loss interface through which it joins a host."""

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.ef.decoder import FrameDecoder, decoder_layers
from sb3_ef.ef.foresight import EgoForesight, ForesightLoss, ForesightTargets, RolloutBlock, draw_rollout_steps

__all__ = [
    "AuxiliaryLoss",
    "EgoForesight",
    "ForesightLoss",
    "ForesightTargets",
    "FrameDecoder",
    "RolloutBlock",
    "decoder_layers",
    "draw_rollout_steps",
]
