"""Ego-Foresight on SB3's off-policy algorithms from pixels: SAC, TD3 and sb3-contrib's TQC, unchanged, with an EF
step on the critic's encoder after each update."""

from sb3_ef.sb3_hosts.ef_hosts import SACEF, TD3EF, TQCEF, AuxiliaryEFMixin
from sb3_ef.sb3_hosts.shifted_buffer import ShiftedSequenceReplayBuffer

__all__ = ["SACEF", "TD3EF", "TQCEF", "AuxiliaryEFMixin", "ShiftedSequenceReplayBuffer"]
