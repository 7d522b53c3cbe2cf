"""Unit conversions at the edges."""

import math

from hal import si as units


def test_oz_in_conversion_matches_design_constant() -> None:
    assert units.oz_in_to_nm(600.0) == 600.0 * 0.0070615518
    assert math.isclose(units.nm_to_oz_in(units.oz_in_to_nm(24.0)), 24.0)


def test_angle_conversions_round_trip() -> None:
    assert math.isclose(units.rad_to_deg(math.pi), 180.0)
    assert math.isclose(units.rad_to_arcmin(units.arcmin_to_rad(3.0)), 3.0)
    assert math.isclose(units.rad_s_to_rpm(units.rpm_to_rad_s(60.0)), 60.0)
