"""CURL (Laskin et al., ICML 2020): the authors' SAC from pixels with a contrastive loss between random crops."""

from sb3_ef.curl.curl import CURL
from sb3_ef.curl.encoder import CURLEncoder
from sb3_ef.curl.loss import CURLLoss
from sb3_ef.curl.policies import CURLActor, CURLPolicy

__all__ = ["CURL", "CURLActor", "CURLEncoder", "CURLLoss", "CURLPolicy"]
