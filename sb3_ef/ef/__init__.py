"""Ego-Foresight: agent/scene split, action-conditioned rollout, frame decoder and loss (algorithm-agnostic)."""

from sb3_ef.ef.decoder import FrameDecoder, decoder_layers
from sb3_ef.ef.foresight import EgoForesight
from sb3_ef.ef.rollout import RolloutBlock
from sb3_ef.ef.steps import draw_rollout_steps

__all__ = ["EgoForesight", "FrameDecoder", "RolloutBlock", "decoder_layers", "draw_rollout_steps"]
