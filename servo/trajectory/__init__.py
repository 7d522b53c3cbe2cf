"""Trajectory generators (quintic point-to-point, LSPB through vias, stay) and the move sequencer.

See docs/control.md.
"""

from servo.trajectory.base import JointLimits, Sample, Trajectory, TrajectoryError, check_speed
from servo.trajectory.bounds import MotionBounds, MotionRefused, Refusal
from servo.trajectory.lspb import Lspb
from servo.trajectory.quintic import Quintic, quintic_duration
from servo.trajectory.sequencer import MoveRecord, MoveSpec, PlanContext, Sequencer
from servo.trajectory.stay import Stay

__all__ = [
    "JointLimits",
    "Lspb",
    "MotionBounds",
    "MotionRefused",
    "MoveRecord",
    "MoveSpec",
    "PlanContext",
    "Quintic",
    "Refusal",
    "Sample",
    "Sequencer",
    "Stay",
    "Trajectory",
    "TrajectoryError",
    "check_speed",
    "quintic_duration",
]
