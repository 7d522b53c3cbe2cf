"""The whole arm's kinematics (hal.kinematics): the points the links join at, the links as line
segments, the tool point's Jacobian and the JPL paper's segment-in-box test. Every expected
value is a hand calculation from the geometry in the module's docstring, with the default
lengths d1 = 0.30, a2 = 0.60, a3 = 0.55, a5 = 0.10, a6 = 0.15 m (full length 1.40 m)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from hal.config import ConfigError
from hal.kinematics import LINKS, ArmModel, segment_box_span

ARM = ArmModel()
D = math.radians


def _q(*deg: float) -> np.ndarray:
    """Joint angles (rad) of the six arm joints and the hand, from degrees."""
    q = np.zeros(7)
    q[: len(deg)] = np.radians(deg)
    return q


def test_at_zero_every_link_lies_along_x_at_shoulder_height() -> None:
    p = ARM.points(_q())
    assert p["shoulder"] == pytest.approx([0.0, 0.0, 0.30])
    assert p["elbow"] == pytest.approx([0.60, 0.0, 0.30])
    assert p["wrist"] == pytest.approx([1.15, 0.0, 0.30])
    assert p["yaw"] == pytest.approx([1.25, 0.0, 0.30])
    assert p["tool"] == pytest.approx([1.40, 0.0, 0.30])
    assert ARM.position(_q()) == pytest.approx(p["wrist"])  # the camera, as visual servoing uses it


def test_the_shoulder_at_90_deg_points_the_arm_straight_up() -> None:
    p = ARM.points(_q(0, 90))
    assert p["elbow"] == pytest.approx([0.0, 0.0, 0.90], abs=1e-12)
    assert p["wrist"] == pytest.approx([0.0, 0.0, 1.45], abs=1e-12)
    assert p["tool"] == pytest.approx([0.0, 0.0, 1.70], abs=1e-12)


def test_waist_90_and_elbow_minus_90_hang_the_forearm_down_on_the_left() -> None:
    p = ARM.points(_q(90, 0, -90))
    assert p["elbow"] == pytest.approx([0.0, 0.60, 0.30], abs=1e-12)
    assert p["wrist"] == pytest.approx([0.0, 0.60, -0.25], abs=1e-12)
    assert p["tool"] == pytest.approx([0.0, 0.60, -0.50], abs=1e-12)


def test_wrist_pitch_roll_and_yaw_swing_the_hand() -> None:
    # pitch 90°: the wrist and hand point up from the wrist at (1.15, 0, 0.30)
    assert ARM.tool_position(_q(0, 0, 0, 90)) == pytest.approx([1.15, 0.0, 0.55], abs=1e-12)
    # yaw 90°: the hand (0.15 m) turns to +y about the yaw axis at (1.25, 0, 0.30)
    assert ARM.tool_position(_q(0, 0, 0, 0, 0, 90)) == pytest.approx([1.25, 0.15, 0.30], abs=1e-12)
    # roll 90° first turns the yaw axis from z to −y: the same yaw then swings the hand up
    assert ARM.tool_position(_q(0, 0, 0, 0, 90, 90)) == pytest.approx([1.25, 0.0, 0.45], abs=1e-12)
    # the hand's fingers (the 7th joint) do not move the tool point
    assert ARM.tool_position(_q(0, 0, 0, 0, 0, 0, 40)) == pytest.approx([1.40, 0.0, 0.30])


def test_the_links_are_four_segments_joined_end_to_end() -> None:
    segs = ARM.segments(_q(30, 20, -40))
    assert [s[0] for s in segs] == [name for name, _, _ in LINKS] == ["upper_arm", "forearm", "wrist", "hand"]
    for (_, _, end), (_, start, _) in itertools.pairwise(segs):
        assert start == pytest.approx(end)
    lengths = [float(np.linalg.norm(b - a)) for _, a, b in segs]
    assert lengths == pytest.approx([0.60, 0.55, 0.10, 0.15])


def test_the_tool_jacobian_at_zero() -> None:
    J = ARM.tool_jacobian(_q())
    # waist: ẑ × (1.4, 0, 0); shoulder, elbow, wrist pitch: the tool rises by its distance from each
    # axis (1.4, 0.8, 0.25 m); roll: the tool lies on the roll axis; yaw: ẑ × (0.15, 0, 0)
    expected = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
                         [1.40, 0.0, 0.0, 0.0, 0.0, 0.15, 0.0],
                         [0.0, 1.40, 0.80, 0.25, 0.0, 0.0, 0.0]])
    assert J == pytest.approx(expected, abs=1e-12)


def test_the_tool_jacobian_with_the_shoulder_up() -> None:
    # q2 = 90°: the arm points up; raising it further swings the tool back along −x by its
    # distance from the shoulder (1.4 m), the waist no longer moves it (it lies on the waist axis)
    J = ARM.tool_jacobian(_q(0, 90))
    assert J[:, 0] == pytest.approx([0.0, 0.0, 0.0], abs=1e-12)
    assert J[:, 1] == pytest.approx([-1.40, 0.0, 0.0], abs=1e-12)
    assert J[:, 2] == pytest.approx([-0.80, 0.0, 0.0], abs=1e-12)


@pytest.mark.parametrize("deg", [(10, 20, -30, 15, 40, -25), (-120, 60, 45, -80, -10, 70)])
def test_the_tool_jacobian_matches_finite_differences(deg) -> None:
    q = _q(*deg)
    J = ARM.tool_jacobian(q)
    h = 1e-6
    for i in range(6):
        dq = np.zeros(7)
        dq[i] = h
        num = (ARM.tool_position(q + dq) - ARM.tool_position(q - dq)) / (2 * h)
        assert J[:, i] == pytest.approx(num, abs=1e-7)


def test_a_segment_through_a_box_enters_and_leaves_where_the_faces_are() -> None:
    # from (0,0,0) to (1,0,0) through the box x 0.25..0.5: λ from 0.25 to 0.5
    assert segment_box_span([0, 0, 0], [1, 0, 0], [0.25, -0.1, -0.1], [0.5, 0.1, 0.1]) == pytest.approx((0.25, 0.5))
    # diagonal (0,0,0)→(2,2,0) through the unit cube at (1..2, 0..1, −1..1): only the point (1,1,0): λ = 0.5
    assert segment_box_span([0, 0, 0], [2, 2, 0], [1, 0, -1], [2, 1, 1]) == pytest.approx((0.5, 0.5))


def test_a_segment_beside_or_short_of_a_box_misses_it() -> None:
    box = ([0.25, -0.1, -0.1], [0.5, 0.1, 0.1])
    assert segment_box_span([0, 0.2, 0], [1, 0.2, 0], *box) is None  # parallel, beside it
    assert segment_box_span([0, 0, 0], [0.2, 0, 0], *box) is None  # ends before it
    assert segment_box_span([0, 0, 0], [1, 1, 0], *box) is None  # passes by a corner: y = x > 0.1 inside x


def test_the_arm_table_is_parsed_with_typed_errors() -> None:
    arm = ArmModel.from_table({"d1": 0.2, "a2": 0.5, "a3": 0.4, "a5": 0.05, "a6": 0.1, "wrist_joints": [4, 5, 6],
                               "joints": [1, 2, 3]})
    assert (arm.a5, arm.a6, arm.wrist_joints) == (0.05, 0.1, (4, 5, 6))
    assert ArmModel.from_table({"joints": [1, 2, 3]}).wrist_joints == (4, 5, 6)  # the wrist follows the elbow
    with pytest.raises(ConfigError, match="wrist_joints"):
        ArmModel.from_table({"wrist_joints": [2, 3, 4]})
    with pytest.raises(ConfigError, match="a2"):
        ArmModel.from_table({"a2": 0.0})
