"""CURL (Laskin et al., ICML 2020): a contrastive loss between random crops, with a momentum key encoder, on SAC."""

from sb3_ef.curl.buffer import CroppedSequenceReplayBuffer
from sb3_ef.curl.curl import CURL
from sb3_ef.curl.encoder import CURLEncoder
from sb3_ef.curl.loss import CURLLoss

__all__ = ["CURL", "CURLEncoder", "CURLLoss", "CroppedSequenceReplayBuffer"]
