"""Trajectory generators (quintic point-to-point, LSPB through vias, stay) and the move sequencer.

See docs/control.md.
"""

from servo.trajectory.base import JointLimits, Sample, Trajectory, TrajectoryError, check_speed
from servo.trajectory.lspb import Lspb
from servo.trajectory.quintic import Quintic, quintic_duration
from servo.trajectory.sequencer import MoveRecord, MoveSpec, PlanContext, Sequencer
from servo.trajectory.stay import Stay

__all__ = [
    "JointLimits",
    "Lspb",
    "MoveRecord",
    "MoveSpec",
    "PlanContext",
    "Quintic",
    "Sample",
    "Sequencer",
    "Stay",
    "Trajectory",
    "TrajectoryError",
    "check_speed",
    "quintic_duration",
]
