"""The frame-deduplicating replay buffer that samples RL transitions with Ego-Foresight windows (docs/buffer.md)."""

from sb3_ef.common.buffers.episodes import MASKS_INFO_KEY
from sb3_ef.common.buffers.sampling import SequenceReplayBufferSamples
from sb3_ef.common.buffers.sequence import SequenceReplayBuffer
from sb3_ef.common.buffers.shifted import ShiftedSequenceReplayBuffer
from sb3_ef.common.buffers.storage import available_host_memory

__all__ = [
    "MASKS_INFO_KEY",
    "SequenceReplayBuffer",
    "SequenceReplayBufferSamples",
    "ShiftedSequenceReplayBuffer",
    "available_host_memory",
]
