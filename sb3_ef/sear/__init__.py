"""SEAR (Gmelin et al., ICML 2023): frame and agent-mask reconstruction from the halves of a DrQ-v2 encoder's latent."""

from sb3_ef.sear.decoder import SEARDecoder
from sb3_ef.sear.loss import SEAR_COEFFICIENTS, SEAR_LATENT_DIM, SEARLoss, SEARTargets, resolve_coefficients

__all__ = ["SEAR_COEFFICIENTS", "SEAR_LATENT_DIM", "SEARDecoder", "SEARLoss", "SEARTargets", "resolve_coefficients"]
