"""Homing to the encoder index (issue #32): the pot chooses the index, the index gives the count.

Expected values come from the plant's construction, not from the procedure: the presets' encoders
have ``index_phase_x4 = 0`` and the motor turns N times the joint (no kinematic error), so the
index fires at joint angles k·2π/N exactly; the decoder counts ``floor(x4) − floor(x4 at
power-up)`` with ``x4 = θ·N·4·lines/2π``.
"""

from __future__ import annotations

import math

import pytest

from tests.support.homing import plant_pot_store
from vmehil.calibration.base import CalibrationAbort, CalibrationContext
from vmehil.calibration.home import HomeProcedure
from vmehil.calibration.store import CalibrationStore
from vmehil.rig_setup.emulated_calibration import EmulatedPositioner
from vmehil.rig_setup.system import EmulatedRig, build_emulated_rig


def _home(rig: str | None, initial_deg: list[float], joint: int, approach_deg: float):
    """Power up at ``initial_deg``, move ``joint`` to ``approach_deg`` with the loop, home it."""
    system = build_emulated_rig(rig, seed=0, initial_deg=initial_deg)
    store = plant_pot_store(system, [joint])
    ctx = CalibrationContext(rig=system.rig, bus=system.crate, store=store,
                             positioner_factory=lambda st: EmulatedPositioner(system, st), joints=[joint],
                             say=lambda _t: None)
    pos = ctx.positioner()
    pos.move_to({joint: math.radians(approach_deg)}, settle_s=1.0)
    result = HomeProcedure().run(ctx)
    return system, pos, result


def _assert_homed_on_the_truth(system: EmulatedRig, pos: EmulatedPositioner, joint: int, cpr: float) -> None:
    pos.hold(0.1)
    m = system.io.read()
    truth = float(system.truth()["theta_joint"][joint])
    # the homed encoder reads the true angle to a count (it counts floor(x4): up to one count low)
    assert 0.0 <= truth - m.theta_enc[joint] < 2 * math.pi / cpr
    assert system.io.homed[joint]


@pytest.mark.slow
def test_homing_finds_the_same_index_from_above_and_below_with_the_same_recorded_offset():
    # j1 powers up at 10.7°: x4 = 10.7/360 · 200000 = 5944.4 → the decoder's 0 is x4 state 5944.
    # The pot chooses the index at 10.8° (3 motor turns: x4 6000) from 11.7° and from 9.9° alike.
    initial = [10.7, 0, 0, 0, 0, 0, 0.6 * 180 / math.pi]
    above = _home(None, initial, 0, 11.7)
    below = _home(None, initial, 0, 9.9)
    for system, pos, res in (above, below):
        assert res.passed, res.as_dict()
        v = res.data["joints"]["j1"]
        assert math.degrees(v["index_angle_rad"]) == pytest.approx(10.8, abs=1e-9)
        assert v["index_counts"] == 6000 - 5944
        assert v["offset_counts"] == pytest.approx(-5944.0, abs=1e-6)
        _assert_homed_on_the_truth(system, pos, 0, 200000.0)
        # it ends held at the index (within the loop's hold band: the switch-off's outer band, 1.5°),
        # and the record is what the file will hold
        assert math.degrees(float(system.truth()["theta_joint"][0])) == pytest.approx(10.8, abs=1.5)
        assert res.update is not None and res.update.joint_entry("j1", "home") is not None
    a, b = above[2].data["joints"]["j1"], below[2].data["joints"]["j1"]
    assert (a["index_counts"], a["offset_counts"], a["index_angle_rad"]) == \
        (b["index_counts"], b["offset_counts"], b["index_angle_rad"])
    for system, _p, _r in (above, below):
        system.close()


@pytest.mark.slow
def test_homing_on_melmalec_homes_a_leg_and_exempts_the_crawler():
    # leg1_swing: N = 120 (an index every 3°), powered up at −4.25° → x4 −2833.3 (state −2834); nearest
    # index −3° (x4 −2000): the count there is −2000 + 2834 = 834
    from emulators.presets import resolve_rig
    from servo.rig import load_rig

    rig = load_rig(resolve_rig("melmalec-16"))
    initial = [0.0] * rig.n_joints
    initial[0] = -4.25
    crawler = [j.name for j in rig.joints].index("crawler")
    system = build_emulated_rig(rig, seed=0, initial_deg=initial)
    store = plant_pot_store(system, [0])
    ctx = CalibrationContext(rig=system.rig, bus=system.crate, store=store,
                             positioner_factory=lambda st: EmulatedPositioner(system, st), joints=[0, crawler],
                             say=lambda _t: None)
    res = HomeProcedure().run(ctx)
    assert res.passed, res.as_dict()
    v = res.data["joints"]["leg1_swing"]
    assert math.degrees(v["index_angle_rad"]) == pytest.approx(-3.0, abs=1e-9)
    assert v["index_counts"] == 834
    assert any(s.startswith("crawler: exempt") for s in res.skipped), res.skipped
    assert not system.io.homeable[crawler] and not system.io.homed[crawler]
    _assert_homed_on_the_truth(system, ctx.positioner(), 0, 240000.0)
    system.close()


def test_homing_refuses_a_joint_whose_pot_is_not_calibrated():
    system = build_emulated_rig(None, seed=0)
    ctx = CalibrationContext(rig=system.rig, bus=system.crate, store=CalibrationStore.empty(system.rig),
                             positioner_factory=lambda st: EmulatedPositioner(system, st), joints=[0],
                             say=lambda _t: None)
    with pytest.raises(CalibrationAbort, match="j1: its pot is not calibrated"):
        HomeProcedure().run(ctx)
    assert not system.io.homed.any()
    system.close()


def test_a_procedures_move_past_a_soft_limit_is_refused_at_once_not_waited_for():
    # (before: the loop refused the move and held, and the positioner waited 10**6 ticks for it)
    system = build_emulated_rig(None, seed=0)
    pos = EmulatedPositioner(system)
    k0 = pos.loop.tick_count
    with pytest.raises(CalibrationAbort, match="soft limit"):
        pos.move_to({0: math.radians(200.0)})
    assert pos.loop.tick_count == k0
    system.close()


def test_a_decoder_that_loses_counts_drops_the_home():
    # quadrature.md: ILLEGAL means counts were lost ("re-home"); a tracking loss or a jump too
    system = build_emulated_rig(None, seed=0)
    io = system.io
    io.homed[:2] = True
    quad0 = system.crate.board("quad0")
    quad0.inject("glitch", channel=0, illegal=1)  # j1's encoder
    system.harness.step(system.rig.period_s, system.rig.computation_delay_s)
    system.harness.publish()
    m = io.read()
    assert m.encoder_illegal[0]
    assert not io.homed[0] and io.homed[1]
    system.close()
