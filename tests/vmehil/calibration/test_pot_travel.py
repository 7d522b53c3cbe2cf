"""Where the pot calibration drives each joint: inside the hard stops and the soft limits."""

from __future__ import annotations

import math

import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from servo.settings import soft_limits_rad
from vmehil.calibration.pot import pot_travel


def _travels_deg(rig_name: str) -> dict[str, tuple[float, float]]:
    rig = load_rig(resolve_rig(rig_name))
    lo, hi = soft_limits_rad(rig)
    return {j.name: tuple(math.degrees(v) for v in pot_travel(j, soft_rad=(lo[j.index], hi[j.index])))
            for j in rig.joints if "pot" in j.wiring}


def test_jpl_arms_travel_is_its_stops_less_3_degrees_within_its_soft_limits_less_1() -> None:
    t = _travels_deg("jpl-arm")
    # j1's stops ±2.88 rad = ±165.0116°, less 3° = ±162.0116°; its soft limits ±163.01° less 1°
    # = ±162.01° are the closer: 0.0016° inside what the calibration drove to before soft limits
    assert t["j1"] == pytest.approx((-162.01, 162.01), abs=1e-9)
    # the hand: stops 0.0..1.2 rad (0..68.75°) less 3° = 3..65.75°; soft limits 2.00..66.75° less 1°
    assert t["hand"] == pytest.approx((3.0, 65.75), abs=1e-9)


def test_a_joint_whose_stops_its_plant_template_states_stays_inside_its_soft_limits() -> None:
    """melmalec-16's legs state their stops in [plant.templates.*], not in [joint.link]: the travel
    was ±177° (the ±π default less 3°), past the stops; the soft limits bound it now."""
    t = _travels_deg("melmalec-16")
    # leg1_swing: soft limits ±43.83° (melmalec-16.toml), less 1°
    assert t["leg1_swing"] == pytest.approx((-42.83, 42.83), abs=1e-9)
    # the knees: soft limits -83.94..11.26° (the upper one 0.2° inside its stop), less 1°
    assert t["leg1_knee"] == pytest.approx((-82.94, 10.26), abs=1e-9)
