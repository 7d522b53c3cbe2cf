"""The hand: its fingers' geometry, and a graspable object — one model for the robot side and
the emulators alike (as :mod:`hal.kinematics` is for the arm).

The JPL arm's hand is a parallel gripper on one joint: the "hand" joint's angle θ opens the
fingers (θ = 0 closed, the lower hard stop). The gap between the fingertips is taken linear in
θ, ``gap = gap_m_per_rad · θ`` (a rack or a four-bar near its middle; the paper gives no size).
A rig file states it in ``[hand]``::

    [hand]
    joint = 6                      # the hand joint (0-based)
    gap_m_per_rad = 0.1            # fingertip gap per radian of the hand joint (m/rad)
    tactile_threshold_n = 1.0      # a finger's tactile switch closes above this force (N)
    grasp_tolerance_m = 0.006      # the hand pot may differ from the object's width by this much
    capture_radius_m = 0.03        # the object is between the fingers within this of the tool point

SI units: metres, radians, newtons, kilograms.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from hal.config import ConfigTable

__all__ = ["GRAVITY_M_S2", "GraspObject", "HandModel"]

#: standard gravity (m/s²): the held object's weight
GRAVITY_M_S2 = 9.80665
#: an object's name: a word (as an obstacle's)
_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}\Z")


@dataclass(frozen=True)
class HandModel:
    """The hand joint and its fingers (see the module docstring for the keys)."""

    joint: int = 6
    gap_m_per_rad: float = 0.1
    tactile_threshold_n: float = 1.0
    grasp_tolerance_m: float = 0.006
    capture_radius_m: float = 0.03

    @classmethod
    def from_table(cls, table: Mapping[str, object] | ConfigTable, source: str = "[hand]") -> HandModel:
        """Build from a rig file's ``[hand]``; errors are :class:`hal.config.ConfigError` naming the key."""
        cfg = table if isinstance(table, ConfigTable) else ConfigTable(dict(table), source, "hand")
        cfg.check_unknown({"joint", "gap_m_per_rad", "tactile_threshold_n", "grasp_tolerance_m", "capture_radius_m"})
        kw: dict[str, Any] = {}
        if "joint" in cfg:
            kw["joint"] = cfg.get_int("joint", min=0, max=63)
        for k, lo, hi in (("gap_m_per_rad", 1e-4, 10.0), ("tactile_threshold_n", 1e-3, 1e4),
                          ("grasp_tolerance_m", 1e-5, 1.0), ("capture_radius_m", 1e-4, 10.0)):
            if k in cfg:
                kw[k] = cfg.get_float(k, min=lo, max=hi)
        return cls(**kw)

    def gap_m(self, theta_rad: float) -> float:
        """The fingertip gap (m) at hand angle ``theta_rad``."""
        return self.gap_m_per_rad * theta_rad

    def angle_rad(self, gap_m: float) -> float:
        """The hand angle (rad) at which the fingertips are ``gap_m`` apart."""
        return gap_m / self.gap_m_per_rad

    def joint_stiffness_nm_per_rad(self, stiffness_n_per_m: float) -> float:
        """An object's stiffness across the fingers seen at the hand joint: k·(d gap/dθ)²."""
        return stiffness_n_per_m * self.gap_m_per_rad ** 2

    def finger_force_n(self, joint_torque_nm: float) -> float:
        """The squeeze force (N) of a torque (N·m) closing the hand: τ / (d gap/dθ)."""
        return joint_torque_nm / self.gap_m_per_rad


@dataclass(frozen=True)
class GraspObject:
    """A graspable object of the scene: ``width_m`` across the fingers, ``mass_kg``, its
    stiffness across the fingers ``stiffness_n_per_m``, and where it is (``position_m``, the
    base frame: the tool point must be within the hand's capture radius of it to grasp it)."""

    name: str
    width_m: float
    mass_kg: float
    stiffness_n_per_m: float
    position_m: tuple[float, float, float]

    @classmethod
    def make(cls, name: str, width_m: float, mass_kg: float, stiffness_n_per_m: float,
             position_m: tuple[float, ...] | list[float]) -> GraspObject:
        """A checked object; ``ValueError`` says what is wrong."""
        if not isinstance(name, str) or not _NAME_RE.match(name):
            raise ValueError(f"object name {name!r}: a word of letters, digits, _ . - (at most 64)")
        pos = tuple(float(x) for x in position_m)
        if len(pos) != 3 or not all(math.isfinite(v) and abs(v) <= 1000.0 for v in pos):
            raise ValueError(f"object {name}: position_m is [x, y, z] in metres, finite, within ±1000 m")
        for what, v, lo, hi in (("width_m", width_m, 1e-4, 10.0), ("mass_kg", mass_kg, 0.0, 1000.0),
                                ("stiffness_n_per_m", stiffness_n_per_m, 1.0, 1e9)):
            if not (math.isfinite(float(v)) and lo <= float(v) <= hi):
                raise ValueError(f"object {name}: {what} = {v!r} must be within {lo:g}..{hi:g}")
        return cls(name, float(width_m), float(mass_kg), float(stiffness_n_per_m), pos)  # type: ignore[arg-type]
