"""SAC, TD3 and sb3-contrib's TQC from pixels with an auxiliary loss (Ego-Foresight) as a step of its own; PPO and
A2C with Ego-Foresight's loss joining theirs."""

from sb3_ef.common.buffers import ShiftedSequenceReplayBuffer
from sb3_ef.sb3_hosts.ef_hosts import SACEF, TD3EF, TQCEF, EFStepMixin
from sb3_ef.sb3_hosts.on_policy import A2CEF, PPOEF, OnPolicyEFMixin
from sb3_ef.sb3_hosts.step import AuxiliaryStepMixin

__all__ = [
    "A2CEF",
    "PPOEF",
    "SACEF",
    "TD3EF",
    "TQCEF",
    "AuxiliaryStepMixin",
    "EFStepMixin",
    "OnPolicyEFMixin",
    "ShiftedSequenceReplayBuffer",
]
