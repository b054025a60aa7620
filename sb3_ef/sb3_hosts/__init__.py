"""Auxiliary losses on SB3's off-policy algorithms from pixels: a step of their own on the critic's encoder after
each update (:class:`AuxiliaryStepMixin`); SAC, TD3 and sb3-contrib's TQC with Ego-Foresight."""

from sb3_ef.auxiliary.step import AuxiliaryStepMixin
from sb3_ef.common.buffers import ShiftedSequenceReplayBuffer
from sb3_ef.sb3_hosts.ef_hosts import SACEF, TD3EF, TQCEF, EFStepMixin

__all__ = ["SACEF", "TD3EF", "TQCEF", "AuxiliaryStepMixin", "EFStepMixin", "ShiftedSequenceReplayBuffer"]
