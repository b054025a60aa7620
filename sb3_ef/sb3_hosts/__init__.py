"""Auxiliary losses on SB3's off-policy algorithms from pixels: a step of their own on the critic's encoder after
each update (:class:`AuxiliaryStepMixin`); SAC, TD3 and sb3-contrib's TQC with Ego-Foresight."""

from sb3_ef.sb3_hosts.auxiliary_step import AuxiliaryStepMixin
from sb3_ef.sb3_hosts.ef_hosts import SACEF, TD3EF, TQCEF, EFStepMixin
from sb3_ef.sb3_hosts.shifted_buffer import ShiftedSequenceReplayBuffer

__all__ = ["SACEF", "TD3EF", "TQCEF", "AuxiliaryStepMixin", "EFStepMixin", "ShiftedSequenceReplayBuffer"]
