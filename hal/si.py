"""Named unit conversions for the edges of the system. Inside, everything is SI.

Use these at the boundary (config files, reports, CLI) only: ``oz_in_to_nm(6.0)``,
``rad_to_deg(theta)``. Constants are exact or as defined by their standards.
"""

from __future__ import annotations

import math

NM_PER_OZ_IN = 0.0070615518  #: 1 ounce-force inch in newton metres (docs/architecture.md, “Units”)
ARCMIN_PER_RAD = 60.0 * 180.0 / math.pi
RAD_PER_REV = 2.0 * math.pi


def oz_in_to_nm(torque_oz_in):
    """Ounce-force inches → newton metres (works on floats and numpy arrays)."""
    return torque_oz_in * NM_PER_OZ_IN


def nm_to_oz_in(torque_nm):
    """Newton metres → ounce-force inches."""
    return torque_nm / NM_PER_OZ_IN


def deg_to_rad(angle_deg):
    return angle_deg * (math.pi / 180.0)


def rad_to_deg(angle_rad):
    return angle_rad * (180.0 / math.pi)


def rad_to_arcmin(angle_rad):
    return angle_rad * ARCMIN_PER_RAD


def arcmin_to_rad(angle_arcmin):
    return angle_arcmin / ARCMIN_PER_RAD


def rpm_to_rad_s(speed_rpm):
    return speed_rpm * (RAD_PER_REV / 60.0)


def rad_s_to_rpm(speed_rad_s):
    return speed_rad_s * (60.0 / RAD_PER_REV)
