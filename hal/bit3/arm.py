"""Alias of :mod:`hal.kinematics` for one release (the arm's kinematics left the BIT3 package).

Import ``ArmModel`` from ``hal.kinematics``; this module goes away in the next release.
"""

from hal.kinematics import ArmModel, FloatVector

__all__ = ["ArmModel", "FloatVector"]
