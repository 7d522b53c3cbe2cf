"""The arm's inverse kinematics (``hal.kinematics.ArmModel.solve``): closed-form solutions checked
against hand calculations (the law of cosines on the shoulder-elbow-wrist triangle), round trips
through the forward kinematics on hand-chosen poses, reach, the soft limits and singularities.

Geometry: the default ArmModel (jpl-arm's [arm]): d1 0.30, a2 0.60, a3 0.55, a5 0.10, a6 0.15 m;
the tool 0.25 m beyond the wrist point along the hand when the wrist is straight."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.kinematics import ArmModel, rotation_rpy, rpy_of

ARM = ArmModel()
#: jpl-arm's soft limits (emulators/presets/jpl-arm.toml [joint.limits]), degrees
LO = np.radians([-163.01, -18.05, -135.50, -112.59, -163.01, -112.59, 2.00])
HI = np.radians([163.01, 106.86, 135.50, 112.59, 163.01, 112.59, 66.75])
START = np.radians([1.0, 10.0, -20.0, 10.0, 1.0, 1.0, 30.0])


def _solve(p, rpy_deg=None, theta0=START):
    rot = None if rpy_deg is None else rotation_rpy(*np.radians(rpy_deg))
    return ARM.solve(p, rot, theta0=theta0, min_rad=LO, max_rad=HI)


def test_rpy_pitch_plus_90_points_the_hand_straight_down() -> None:
    r = rotation_rpy(0.0, math.pi / 2, 0.0)
    np.testing.assert_allclose(r[:, 0], [0.0, 0.0, -1.0], atol=1e-12)
    r = rotation_rpy(0.0, 0.0, math.pi / 2)  # yaw 90°: the hand points along +y
    np.testing.assert_allclose(r[:, 0], [0.0, 1.0, 0.0], atol=1e-12)
    assert rpy_of(rotation_rpy(0.1, -0.4, 2.0)) == pytest.approx((0.1, -0.4, 2.0))


def test_a_level_target_ahead_solves_to_the_hand_calculated_angles() -> None:
    # (0.8, 0, 0.3), the hand level and pointing out (the default): the wrist point at (0.55, 0, 0.30),
    # level with the shoulder 0.55 m away: an isosceles triangle (0.60, 0.55, 0.55): cos(shoulder) =
    # 0.6/2/0.55 = 6/11 → 56.944°; the elbow's interior angle the same, q3 = −(180 − 56.944)°;
    # the wrist pitch brings the hand back level: q4 = −(q2 + q3) = 66.111°
    res = _solve([0.8, 0.0, 0.3])
    assert res.reachable and res.reason == "" and not res.singular
    np.testing.assert_allclose(np.degrees(res.theta[:6]), [0.0, 56.944, -123.056, 66.111, 0.0, 0.0], atol=1e-3)
    assert math.degrees(res.theta[6]) == pytest.approx(30.0)  # the hand's own joint is left as it was
    # manipulability a2·a3·|sin q3|·r = 0.33·√(1 − (6/11)²)·0.55
    assert res.manipulability == pytest.approx(0.152122, abs=1e-6)
    assert res.wrist_manipulability == pytest.approx(1.0)


def test_the_hand_pointing_down_solves_to_the_hand_calculated_angles() -> None:
    # (0.9, 0, 0.0), pitch 90°: the yaw point 0.15 m above, (0.9, 0, 0.15); the wrist's pitch φ = −90°,
    # the wrist point a5 above that, (0.9, 0, 0.25): r = 0.9, h = −0.05 from the shoulder;
    # cos q3 = (0.81 + 0.0025 − 0.36 − 0.3025)/0.66 = 0.22727 → q3 = −76.863° (elbow up);
    # q2 = atan2(−0.05, 0.9) − atan2(0.55·sin q3, 0.6 + 0.55·cos q3) = 33.276°; q4 = −90 − q2 − q3
    res = _solve([0.9, 0.0, 0.0], [0.0, 90.0, 0.0])
    assert res.reachable and not res.singular
    np.testing.assert_allclose(np.degrees(res.theta[:6]), [0.0, 33.276, -76.863, -46.413, 0.0, 0.0], atol=1e-3)


@pytest.mark.parametrize("p, rpy_deg", [
    ([0.8, 0.1, 0.3], None),
    ([0.6, -0.4, 0.1], None),
    ([0.7, 0.3, 0.5], [10.0, -20.0, 40.0]),
    ([0.9, -0.2, 0.0], [0.0, 45.0, -10.0]),
    ([0.5, 0.5, -0.2], [30.0, 60.0, 45.0]),
    ([1.0, 0.0, 0.6], [0.0, -30.0, 0.0]),
])
def test_the_tool_goes_where_the_inverse_kinematics_said_on_hand_chosen_poses(p, rpy_deg) -> None:
    res = _solve(p, rpy_deg)
    assert res.reachable, res.reason
    assert np.all(res.theta >= LO - 1e-12) and np.all(res.theta <= HI + 1e-12)
    np.testing.assert_allclose(ARM.tool_position(res.theta), p, atol=1e-9)
    want = ARM.default_hand_rotation(p) if rpy_deg is None else rotation_rpy(*np.radians(rpy_deg))
    np.testing.assert_allclose(ARM.hand_rotation(res.theta), want, atol=1e-9)


def test_the_default_hand_orientation_is_level_and_points_away_from_the_waist() -> None:
    res = _solve([0.5, 0.5, 0.2])
    hand = ARM.hand_rotation(res.theta)
    np.testing.assert_allclose(hand[:, 0], [math.sqrt(0.5), math.sqrt(0.5), 0.0], atol=1e-9)


def test_a_target_beyond_reach_is_unreachable_saying_how_far() -> None:
    # level at (1.6, 0, 0.3): the wrist point 1.6 − 0.25 = 1.35 m from the shoulder; the arm reaches 1.15 m
    res = _solve([1.6, 0.0, 0.3])
    assert not res.reachable and res.theta is None
    assert res.reason == "beyond reach: the wrist 1.350 m from the shoulder, the arm reaches 1.150 m"


def test_a_target_only_past_a_soft_limit_names_the_joint() -> None:
    # level at (0.8, 0, −0.5): the wrist point at r 0.55, h −0.8; elbow up needs the shoulder at
    # −24.6° (past −18.05°), elbow down at −86.4°
    res = _solve([0.8, 0.0, -0.5])
    assert not res.reachable and res.limit_joint == 1
    assert res.reason == "past the soft limits: every solution puts a joint past its limit, the nearest joint index 1"
    free = ARM.solve([0.8, 0.0, -0.5], None, theta0=START)  # without the limits it is reachable
    assert free.reachable and math.degrees(free.theta[1]) == pytest.approx(-24.6, abs=0.1)


def test_full_extension_is_singular_with_the_elbow_straight() -> None:
    # level at (1.4, 0, 0.3) = a2 + a3 + a5 + a6 ahead of the shoulder: every joint at 0, the elbow straight
    res = _solve([1.4, 0.0, 0.3])
    assert res.reachable and res.singular
    assert res.singularity.startswith("the elbow straight")
    np.testing.assert_allclose(res.theta[:6], 0.0, atol=1e-6)
    assert res.manipulability < 1e-6


def test_the_wrist_roll_at_90_degrees_is_singular() -> None:
    theta = np.radians([0.0, 30.0, -60.0, 20.0, 90.0, 10.0, 30.0])  # the stated configuration
    res = ARM.solve(ARM.tool_position(theta), ARM.hand_rotation(theta), theta0=theta)
    assert res.reachable and res.singular and res.singularity.startswith("the wrist roll at ±90°")
    assert res.wrist_manipulability < 1e-9


def test_of_the_solutions_the_one_nearest_the_start_is_taken() -> None:
    # elbow up (q3 < 0) from an elbow-up start, elbow down (q2 −57°) refused by j2's −18° limit;
    # without limits and from an elbow-down start the elbow-down branch comes back
    down = np.radians([0.0, -50.0, 120.0, -70.0, 0.0, 0.0, 30.0])
    res = ARM.solve([0.8, 0.0, 0.3], None, theta0=down)
    assert math.degrees(res.theta[1]) == pytest.approx(-56.944, abs=1e-3)
    assert math.degrees(res.theta[2]) == pytest.approx(123.056, abs=1e-3)
