"""The run JSON's ``tool`` block (vmehil.reports.run_report.tool_summary, docs/cartesian.md): the
tool's final error against the last Cartesian move's target, from the plant's true angles. A fake
loop whose recorder holds hand-chosen angles; the expected distances are hand calculations."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from hal.kinematics import ArmModel
from servo.cartesian import CartesianMove, CartesianTarget
from servo.trajectory import MoveRecord
from vmehil.reports.run_report import tool_summary

#: (0.8, 0, 0.3) m with the hand level (tests/hal/test_inverse_kinematics.py's hand calculation)
AT_TARGET_DEG = [0.0, 56.944269, -123.055731, 66.111463, 0.0, 0.0, 30.0]


def _loop(kind: str = "cartesian"):
    move = CartesianMove(CartesianTarget.make([0.8, 0.0, 0.3])) if kind == "cartesian" else SimpleNamespace(kind=kind)
    seq = SimpleNamespace(moves=[move], records=[MoveRecord(0, kind, 0.0, 5.0)])
    return SimpleNamespace(plan_context=SimpleNamespace(bounds=SimpleNamespace(arm=ArmModel())), sequencer=seq)


def _rec(true_deg, measured_deg):
    return {"theta_true": np.radians([true_deg, true_deg]), "theta": np.radians([measured_deg, measured_deg])}


def test_the_tool_error_is_the_trues_distance_from_the_target() -> None:
    # the waist 0.1° off: the tool 0.8 m from the waist axis moves a chord of 2·0.8·sin(0.05°) = 1.396 mm
    off = list(AT_TARGET_DEG)
    off[0] = 0.1
    tool = tool_summary(_loop(), _rec(off, AT_TARGET_DEG))
    assert tool is not None and tool["move"] == 1 and tool["kind"] == "cartesian"
    assert tool["final_error_mm"] == pytest.approx(1.396, abs=2e-3)
    assert tool["measured_error_mm"] == pytest.approx(0.0, abs=0.05)  # the drivers read the target
    assert tool["sensor_error_mm"] == pytest.approx(1.396, abs=2e-3)
    assert tool["final_position_m"][1] == pytest.approx(0.8 * math.sin(math.radians(0.1)), abs=1e-5)


def test_a_sensor_that_no_longer_answers_leaves_the_measured_error_out() -> None:
    measured = list(AT_TARGET_DEG)
    measured[2] = float("nan")
    tool = tool_summary(_loop(), _rec(AT_TARGET_DEG, measured))
    assert tool is not None and tool["final_error_mm"] == pytest.approx(0.0, abs=0.05)
    assert tool["measured_error_mm"] is None and tool["sensor_error_mm"] is None


def test_no_tool_block_when_the_last_move_is_a_joint_move() -> None:
    assert tool_summary(_loop("quintic"), _rec(AT_TARGET_DEG, AT_TARGET_DEG)) is None
