"""Cartesian moves (servo.cartesian, servo.trajectory.cartesian): the JPL "move arm to specified
position with specified or default hand orientation", (DM)²'s blendx_t straight lines with
parabolic blends, the JPL approach point; refused before they start when out of reach or through a
singularity, and checked like every move against the soft limits and the scene.

The arm: the default ArmModel (jpl-arm's [arm]), 7 joints (the hand last), jpl-arm's soft limits,
30°/s planning velocity; the tool positions expected are the targets the files state."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.config import ConfigError, ConfigTable
from hal.kinematics import ArmModel, rotation_rpy
from servo.motion import parse_motion
from servo.scene import Obstacle, Scene
from servo.trajectory import JointLimits, MotionBounds, MotionRefused, PlanContext, Sequencer

ARM = ArmModel()
NAMES = ("j1", "j2", "j3", "j4", "j5", "j6", "hand")
LO = np.radians([-163.01, -18.05, -135.50, -112.59, -163.01, -112.59, 2.00])
HI = np.radians([163.01, 106.86, 135.50, 112.59, 163.01, 112.59, 66.75])
#: a start off every singularity: elbow bent, wrist level
START = np.radians([0.0, 40.0, -90.0, 50.0, 0.0, 0.0, 30.0])


def _ctx(scene: Scene | None = None) -> PlanContext:
    return PlanContext(JointLimits.make(7, math.radians(30.0)),
                       bounds=MotionBounds(NAMES, LO, HI, ARM, scene if scene is not None else Scene()))


def _motion(text: str):
    import tomllib

    return parse_motion(ConfigTable(tomllib.loads(text), "test.toml"), 7)


def _plan(text: str, start=START, scene: Scene | None = None) -> Sequencer:
    return Sequencer(list(_motion(text).moves), start, _ctx(scene))


def _tool_path(traj, n=400) -> np.ndarray:
    return np.array([ARM.tool_position(traj.sample(traj.duration * i / (n - 1)).theta_d) for i in range(n)])


def _distance_to_segment(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    lam = np.clip((p - a) @ d / (d @ d), 0.0, 1.0)
    return np.linalg.norm(p - (a + lam[:, None] * d), axis=1)


def test_a_cartesian_move_ends_with_the_tool_at_the_target_and_the_hand_level() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.1, 0.3]\n')
    assert seq.plan_error is None
    end = seq.planned[0].end
    np.testing.assert_allclose(ARM.tool_position(end), [0.8, 0.1, 0.3], atol=1e-9)
    az = math.atan2(0.1, 0.8)  # the default: level, pointing away from the waist axis
    np.testing.assert_allclose(ARM.hand_rotation(end)[:, 0], [math.cos(az), math.sin(az), 0.0], atol=1e-9)
    assert end[6] == pytest.approx(START[6])  # the hand's fingers are not moved


def test_a_cartesian_move_with_an_orientation_ends_with_the_hand_so() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.9, -0.2, 0.0]\norientation_deg = [0, 45, -10]\n')
    end = seq.planned[0].end
    np.testing.assert_allclose(ARM.tool_position(end), [0.9, -0.2, 0.0], atol=1e-9)
    np.testing.assert_allclose(ARM.hand_rotation(end), rotation_rpy(0.0, math.radians(45), math.radians(-10)),
                               atol=1e-9)


def test_a_blendx_move_keeps_the_tool_on_the_straight_line() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, -0.2, 0.3]\n'
                '[[move]]\ntype = "blendx"\nposition_m = [0.8, 0.2, 0.3]\n')
    assert seq.plan_error is None
    line = seq.planned[1]
    path = _tool_path(line)
    # within 0.1 mm of the segment between the two points: the table's cubic between its points
    assert np.max(_distance_to_segment(path, np.array([0.8, -0.2, 0.3]), np.array([0.8, 0.2, 0.3]))) < 1e-4
    np.testing.assert_allclose(ARM.tool_position(line.end), [0.8, 0.2, 0.3], atol=1e-9)
    # its own time: no joint faster than the planning velocity (30°/s), a little numerical slack
    dt = 1e-3
    th = np.array([line.sample(t).theta_d for t in np.arange(0.0, line.duration, dt)])
    assert np.max(np.abs(np.diff(th, axis=0))) / dt <= math.radians(30.0) * 1.01


def test_a_blendx_move_passes_through_its_via_points() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, -0.2, 0.3]\n'
                '[[move]]\ntype = "blendx"\nvia_m = [[0.9, 0.0, 0.4]]\nposition_m = [0.8, 0.2, 0.3]\n')
    assert seq.plan_error is None
    path = _tool_path(seq.planned[1], 2000)
    assert np.min(np.linalg.norm(path - [0.9, 0.0, 0.4], axis=1)) < 1e-3


def test_the_approach_point_comes_before_the_target_along_the_hand_axis() -> None:
    # pointing straight down (pitch 90°), approach 0.05 m: the approach point 0.05 m above the target;
    # the last part of the move goes straight down to it
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.9, 0.0, 0.0]\norientation_deg = [0, 90, 0]\n'
                'approach_m = 0.05\n')
    assert seq.plan_error is None
    traj = seq.planned[0]
    first, last = traj.parts
    np.testing.assert_allclose(ARM.tool_position(first.end), [0.9, 0.0, 0.05], atol=1e-9)
    path = _tool_path(last)
    assert np.max(_distance_to_segment(path, np.array([0.9, 0.0, 0.05]), np.array([0.9, 0.0, 0.0]))) < 1e-4
    np.testing.assert_allclose(ARM.tool_position(traj.end), [0.9, 0.0, 0.0], atol=1e-9)


def test_a_target_beyond_reach_is_refused_before_the_move_starts_saying_why() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [1.6, 0.0, 0.3]\n')
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert str(err) == ("move refused: move 1: target [1.600, 0.000, 0.300] m cannot be reached: beyond reach: "
                        "the wrist 1.350 m from the shoulder, the arm reaches 1.150 m")
    assert err.refusals[0].move == 0


def test_a_target_at_full_extension_is_refused_as_singular() -> None:
    seq = _plan('[[move]]\ntype = "blendx"\nposition_m = [1.4, 0.0, 0.3]\n')
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert "is at a singularity: the elbow straight" in str(err)


def test_a_straight_path_turning_the_wrist_roll_through_90_degrees_is_refused() -> None:
    # from the hand level (roll 0) to roll 120° about its own axis: the wrist roll passes ±90°
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, 0.3]\n'
                '[[move]]\ntype = "blendx"\nposition_m = [0.8, 0.05, 0.3]\norientation_deg = [120, 0, 3.576]\n')
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert "move 2: the straight path passes through a singularity at point" in str(err)
    assert "the wrist roll at ±90°" in str(err)


def test_a_straight_path_from_a_singular_start_is_refused_saying_so() -> None:
    # every joint at 0: the elbow straight
    seq = _plan('[[move]]\ntype = "blendx"\nposition_m = [1.2, 0.1, 0.3]\n', start=np.zeros(7))
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert "move 1: the straight path starts at a singularity (the elbow straight" in str(err)


def test_a_straight_path_out_of_the_workspace_is_refused_naming_the_point() -> None:
    # from (0.8, 0, 0.3) up to 1.5 m: the wrist leaves the 1.15 m sphere about the shoulder on the way
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, 0.3]\n'
                '[[move]]\ntype = "blendx"\nvia_m = [[0.8, 0.0, 1.5]]\nposition_m = [0.8, 0.0, 0.6]\n')
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert "move 2: the straight path leaves the workspace at point" in str(err)
    assert "beyond reach: the wrist 1.15" in str(err)


def test_a_cartesian_move_through_an_obstacle_is_refused_by_the_collision_check() -> None:
    # a box around the target: the hand ends inside it
    scene = Scene([Obstacle.make("crate", [0.75, -0.05, 0.25], [0.85, 0.05, 0.35])])
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, 0.3]\n', scene=scene)
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "COLLISION"
    assert "hits obstacle crate" in str(err)


def test_a_target_reachable_only_past_a_soft_limit_is_refused_naming_the_joint() -> None:
    seq = _plan('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, -0.5]\n')
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "REACH"
    assert "past the soft limits" in str(err) and "the nearest joint j2" in str(err)


def test_a_rig_without_an_arm_model_cannot_plan_a_cartesian_move() -> None:
    moves = list(_motion('[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, 0.3]\n').moves)
    seq = Sequencer(moves, START, PlanContext(JointLimits.make(7, 1.0)))
    assert "this rig's file states no [arm]" in str(seq.plan_error)


@pytest.mark.parametrize("body, key", [
    ('type = "cartesian"\n', "position_m"),
    ('type = "cartesian"\nposition_m = [1, 2]\n', "position_m"),
    ('type = "cartesian"\nposition_m = [0.8, 0, 0.3]\norientation_deg = [0, 0]\n', "orientation_deg"),
    ('type = "cartesian"\nposition_m = [0.8, 0, 0.3]\napproach_m = -0.1\n', "approach_m"),
    ('type = "blendx"\nposition_m = [0.8, 0, 0.3]\nvia_m = [[0.8, 0]]\n', "via_m[0]"),
    ('type = "blendx"\nposition_m = [0.8, 0, 0.3]\nspeed = 2\n', "speed"),
    ('type = "cartesian"\nposition_m = [0.8, 0, 0.3]\nvia_m = []\n', "via_m"),
])
def test_a_bad_cartesian_move_names_its_key(body, key) -> None:
    with pytest.raises(ConfigError) as e:
        _motion("[[move]]\n" + body)
    assert f"move[0].{key}" in str(e.value)
