"""TD-MPC2 and TDMPC2-EF: a standalone model-based algorithm with SB3's interface, its world model and planner."""

from sb3_ef.tdmpc2.planner import MPPIPlanner
from sb3_ef.tdmpc2.policies import TDMPC2EFPolicy, TDMPC2Policy
from sb3_ef.tdmpc2.tdmpc2 import TDMPC2
from sb3_ef.tdmpc2.tdmpc2_ef import TDMPC2EF
from sb3_ef.tdmpc2.world_model import WorldModel

__all__ = ["TDMPC2", "TDMPC2EF", "MPPIPlanner", "TDMPC2EFPolicy", "TDMPC2Policy", "WorldModel"]
