"""Motor babbling: random actions at the start of training, so that Ego-Foresight sees varied movements
(docs/ef.md, "Motor babbling")."""

from sb3_ef.ef.babbling.actions import BABBLING_MODES, babble, babble_env_actions, check_babbling
from sb3_ef.ef.babbling.callback import MotorBabblingCallback, with_babbling
from sb3_ef.ef.babbling.held_out import HeldOutWindows, foresight_error_ratio, record_held_out_windows
from sb3_ef.ef.babbling.state import STATE_ATTRIBUTE, BabblingState, Plateau

__all__ = [
    "BABBLING_MODES",
    "STATE_ATTRIBUTE",
    "BabblingState",
    "HeldOutWindows",
    "MotorBabblingCallback",
    "Plateau",
    "babble",
    "babble_env_actions",
    "check_babbling",
    "foresight_error_ratio",
    "record_held_out_windows",
    "with_babbling",
]
