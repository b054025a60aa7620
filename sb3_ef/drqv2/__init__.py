"""DrQ-v2 and DrQv2-EF with the Stable-Baselines3 interface."""

from sb3_ef.drqv2.drqv2 import DrQv2, DrQv2EF
from sb3_ef.drqv2.policies import DrQv2EFPolicy, DrQv2Encoder, DrQv2Policy

__all__ = ["DrQv2", "DrQv2EF", "DrQv2EFPolicy", "DrQv2Encoder", "DrQv2Policy"]
