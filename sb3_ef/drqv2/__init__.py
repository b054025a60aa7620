"""DrQv2-EF and DrQ-v2 with the Stable-Baselines3 interface."""

from sb3_ef.drqv2.drqv2_ef import DrQv2, DrQv2EF
from sb3_ef.drqv2.policies import DrQv2Encoder, DrQv2Policy

__all__ = ["DrQv2", "DrQv2EF", "DrQv2Encoder", "DrQv2Policy"]
