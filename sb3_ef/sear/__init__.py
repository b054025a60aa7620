"""SEAR (Gmelin et al., ICML 2023): frame and agent-mask reconstruction from the halves of a DrQ-v2 encoder's latent."""

from sb3_ef.sear.decoder import SEARDecoder
from sb3_ef.sear.loss import SEAR_COEFFICIENTS, SEAR_LATENT_DIM, SEARLoss, SEARTargets, resolve_coefficients
from sb3_ef.sear.sear import SEAR, SEARPolicy

__all__ = [
    "SEAR",
    "SEAR_COEFFICIENTS",
    "SEAR_LATENT_DIM",
    "SEARDecoder",
    "SEARLoss",
    "SEARPolicy",
    "SEARTargets",
    "resolve_coefficients",
]
