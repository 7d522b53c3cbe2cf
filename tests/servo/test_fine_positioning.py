"""A Cartesian move's fine positioning (servo.fine_positioning, docs/cartesian.md): the joint
targets trimmed by the joints' mean measured error until the tool is within the tolerance, the
trimmed targets kept by the moves after it.

The joint here is the model of what the switch-off leaves (docs/cartesian.md, "The tool's final
error"): it rests at its target plus a fixed offset (the frozen integrators' value), −0.3° on the
waist. By hand, with the trim gain 0.8: the first window's mean is 0.3° short, the target moves
0.24°; the joint then rests 0.06° short — at the waist's lever, the tool's 0.8 m from the waist axis
at (0.8, 0, 0.3) m, 2·0.8 m·sin(0.03°) = 0.837758 mm; a second trim of 0.8·0.06° = 0.048° leaves
0.012°, 2·0.8 m·sin(0.006°) = 0.167552 mm."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass

import numpy as np
import pytest

from hal.config import ConfigError, ConfigTable
from hal.kinematics import ArmModel
from servo.cartesian import parse_cartesian
from servo.fine_positioning import MEASURE_KEY, FinePositioning, FineSettings
from servo.motion import WaitMove, parse_motion
from servo.scene import Obstacle, Scene
from servo.trajectory import JointLimits, MotionBounds, MotionRefused, PlanContext, Sequencer, Stay

ARM = ArmModel()
TARGET_M = np.array([0.8, 0.0, 0.3])
OFFSET_RAD = np.radians([-0.3, 0, 0, 0, 0, 0, 0])
PERIOD_S = 0.008


@dataclass(frozen=True)
class _Move:
    """The move's own part a held pose (0.5 s), then the fine positioning."""

    settings: FineSettings
    kind: str = "cartesian"

    def build(self, start: np.ndarray, ctx: PlanContext) -> FinePositioning:
        return FinePositioning(Stay(start, 0.5), ARM, TARGET_M, self.settings, ctx.extras)


def _play(tolerance_mm: float, seconds: float, offset_rad: np.ndarray = OFFSET_RAD, checked_first: bool = False
          ) -> tuple[Sequencer, FinePositioning, list[np.ndarray]]:
    planned = ARM.solve(TARGET_M, None, theta0=np.zeros(7)).theta
    assert planned is not None
    ctx = PlanContext(JointLimits.make(7, 1.0))
    seq = Sequencer([_Move(FineSettings(tolerance_mm * 1e-3, timeout_s=3.0)), WaitMove(1.0)], planned, ctx)
    held: list[np.ndarray] = []
    ctx.extras[MEASURE_KEY] = lambda: held[-1] + offset_rad if held else None  # where the joint rests
    if checked_first:  # a scene check's pass (20 instants) while the joints are measured 1° off
        held.append(planned + np.radians(1.0))
        first = seq.planned[0]
        for i in range(20):
            first.sample(first.duration * i / 19)
        held.clear()
    for k in range(round(seconds / PERIOD_S)):
        held.append(seq.sample(k * PERIOD_S).theta_d)
    fine = seq.records[0].trajectory
    assert isinstance(fine, FinePositioning)
    return seq, fine, held


def test_one_trim_brings_the_tool_within_a_1_mm_tolerance() -> None:
    _, fine, held = _play(1.0, 2.0)
    assert fine.settled is True and fine.trims == 1
    assert fine.error_m == pytest.approx(0.837758e-3, abs=1e-8)
    assert math.degrees(held[-1][0] - fine.planned[0]) == pytest.approx(0.24, abs=1e-9)


def test_a_tighter_tolerance_takes_a_second_trim() -> None:
    _, fine, _ = _play(0.5, 2.5)
    assert fine.settled is True and fine.trims == 2
    assert fine.error_m == pytest.approx(0.167552e-3, abs=1e-8)
    assert np.degrees(fine.setpoint - fine.planned) == pytest.approx([0.288, 0, 0, 0, 0, 0, 0], abs=1e-9)


def test_a_check_sampling_the_move_before_the_run_leaves_the_run_as_without_it() -> None:
    _, fine, _ = _play(0.5, 2.5, checked_first=True)
    assert fine.settled is True and fine.trims == 2
    assert np.degrees(fine.setpoint - fine.planned) == pytest.approx([0.288, 0, 0, 0, 0, 0, 0], abs=1e-9)


def test_the_wait_after_it_holds_the_trimmed_targets_not_the_planned_ones() -> None:
    seq, fine, held = _play(0.5, 4.0)  # 0.5 s pose + 3 s phase, then into the wait
    assert seq.records[-1].kind == "wait"
    assert np.degrees(held[-1] - fine.planned) == pytest.approx([0.288, 0, 0, 0, 0, 0, 0], abs=1e-9)


def test_without_a_measurement_the_phase_holds_the_planned_targets() -> None:
    planned = ARM.solve(TARGET_M, None, theta0=np.zeros(7)).theta
    fine = FinePositioning(Stay(planned, 0.5), ARM, TARGET_M, FineSettings(1e-3), {})
    for k in range(500):  # a scene check's or a plan's sampling: no loop, nothing changes
        assert np.array_equal(fine.sample(k * PERIOD_S).theta_d, planned)
    assert fine.settled is None and fine.trims == 0 and fine.duration == pytest.approx(3.5)


def test_a_trim_stops_at_half_a_degree_from_the_planned_angle() -> None:
    _, fine, _ = _play(1.0, 3.6, np.radians([-2.0, 0, 0, 0, 0, 0, 0]))  # beyond any trim's reach
    assert fine.settled is False
    assert math.degrees(fine.setpoint[0] - fine.planned[0]) == pytest.approx(0.5, abs=1e-9)


def test_the_motion_file_keys_of_the_fine_positioning() -> None:
    move = parse_cartesian(ConfigTable({"type": "cartesian", "position_m": [0.8, 0.0, 0.3],
                                        "settle_tolerance_mm": 2.0, "settle_timeout_s": 1.5}, "m.toml", "move[0]"), 7)
    assert move.fine == FineSettings(2e-3, 1.5)  # type: ignore[attr-defined]
    plain = parse_cartesian(ConfigTable({"type": "cartesian", "position_m": [0.8, 0.0, 0.3]}, "m.toml", "move[0]"), 7)
    assert plain.fine is None  # type: ignore[attr-defined]
    with pytest.raises(ConfigError, match="settle_timeout_s"):
        parse_cartesian(ConfigTable({"type": "cartesian", "position_m": [0.8, 0.0, 0.3], "settle_timeout_s": 1.0},
                                    "m.toml", "move[0]"), 7)
    with pytest.raises(ConfigError, match="settle_tolerance_mm"):
        parse_cartesian(ConfigTable({"type": "cartesian", "position_m": [0.8, 0.0, 0.3],
                                     "settle_tolerance_mm": 0.0}, "m.toml", "move[0]"), 7)


def test_a_fine_positioned_move_into_an_obstacle_is_still_refused_before_it_starts() -> None:
    # the box of test_cartesian_moves around the target: the hand ends inside it, trimmed or not
    lo = np.radians([-163.01, -106.86, -135.50, -112.59, -163.01, -112.59, -66.75])
    hi = np.radians([163.01, 106.86, 135.50, 112.59, 163.01, 112.59, 66.75])
    scene = Scene([Obstacle.make("crate", [0.75, -0.05, 0.25], [0.85, 0.05, 0.35])])
    ctx = PlanContext(JointLimits.make(7, math.radians(30.0)),
                      bounds=MotionBounds(("j1", "j2", "j3", "j4", "j5", "j6", "hand"), lo, hi, ARM, scene))
    text = '[[move]]\ntype = "cartesian"\nposition_m = [0.8, 0.0, 0.3]\nsettle_tolerance_mm = 1.0\n'
    moves = parse_motion(ConfigTable(tomllib.loads(text), "test.toml"), 7).moves
    err = Sequencer(list(moves), np.radians([0.0, 40.0, -90.0, 50.0, 0.0, 0.0, 30.0]), ctx).plan_error
    assert isinstance(err, MotionRefused) and err.code == "COLLISION" and "hits obstacle crate" in str(err)
