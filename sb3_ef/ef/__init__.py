"""Ego-Foresight: agent/scene split, action-conditioned rollout, pixel or latent target, and the host's loss."""

from sb3_ef.auxiliary.loss import AuxiliaryLoss
from sb3_ef.ef.arguments import TARGETS, check_ef_kwargs
from sb3_ef.ef.decoder import FrameDecoder, decoder_layers
from sb3_ef.ef.foresight import EgoForesight, LatentEgoForesight, RolloutBlock, draw_rollout_steps, ego_foresight
from sb3_ef.ef.latent import LatentHead, MomentumTarget
from sb3_ef.ef.losses import ForesightLoss, ForesightTargets, LatentForesightLoss, foresight_loss
from sb3_ef.ef.probe import fit_probe

__all__ = [
    "TARGETS",
    "AuxiliaryLoss",
    "EgoForesight",
    "ForesightLoss",
    "ForesightTargets",
    "FrameDecoder",
    "LatentEgoForesight",
    "LatentForesightLoss",
    "LatentHead",
    "MomentumTarget",
    "RolloutBlock",
    "check_ef_kwargs",
    "decoder_layers",
    "draw_rollout_steps",
    "ego_foresight",
    "fit_probe",
    "foresight_loss",
]
