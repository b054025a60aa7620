"""CURL (Laskin et al., ICML 2020): a contrastive loss between random crops, with a momentum key encoder."""

from sb3_ef.curl.encoder import CURLEncoder
from sb3_ef.curl.loss import CURLLoss

__all__ = ["CURLEncoder", "CURLLoss"]
