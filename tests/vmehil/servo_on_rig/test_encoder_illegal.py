"""Illegal quadrature transitions: the decoder's sticky ILLEGAL status (A and B changed in one
decoder sample: counts lost), read through the driver, stops the loop when it is set in 3 ticks of
the last 125 — a threshold a healthy encoder at full speed never reaches. Stops are read off the
emulated boards' nets."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

DECODER_SAMPLE_HZ = 1_000_000.0  # the decoder board's input sampling (an HCTL-2016-like filter on a 4 MHz clock)


def _moving(n_ticks: int = 400):
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    runner = LockstepRunner(system, loop)
    runner.run(100)  # the demo move is under way
    assert loop.fault is None
    return system, loop, runner


def _assert_safe(system) -> None:
    signals = system.crate.signals
    for j in system.rig.joints:
        assert signals.get_digital(j.net("amp_enable")) is False, j.name
        assert signals.get_analog(j.net("amp_command")) == pytest.approx(0.0, abs=0.0125), j.name


def test_illegal_transitions_every_period_stop_the_loop_within_three_ticks() -> None:
    system, loop, runner = _moving()
    pin = system.rig.joints[0].wiring["encoder"]
    system.crate.board(pin.board).inject("glitch", channel=pin.index, counts=0, illegal=400, intervals=150)
    runner.run(50)
    assert loop.fault is not None and loop.fault.cause == "encoder_illegal", loop.fault
    assert loop.fault.joint == "j1" and loop.fault.tick <= 100 + 3
    _assert_safe(system)


def test_one_illegal_sample_rides_through() -> None:
    system, loop, runner = _moving()
    pin = system.rig.joints[0].wiring["encoder"]
    system.crate.board(pin.board).inject("glitch", channel=pin.index, counts=0, illegal=1, intervals=1)
    runner.run(200)
    assert loop.fault is None
    # the decoder did flag it, and the loop cleared it (sticky otherwise): it reads clear now
    assert system.crate.board(pin.board).ch[pin.index].stats["illegal"] == 1
    assert not system.io.quad[pin.board].status(pin.index).illegal


def test_a_healthy_encoder_at_full_speed_is_far_below_one_count_per_decoder_sample() -> None:
    """The threshold's premise, by hand from the rig file: counts per period at the joints' top
    speed against the decoder's samples per period."""
    system = build_emulated_rig(None, seed=0)
    top_deg_s = 20.0  # jpl-arm [servo] max_velocity_deg_s
    period_s = 1 / 125.0
    for j in system.rig.joints:
        if "encoder" not in j.wiring:
            continue
        cpr = system.io.scaling[j.index].encoder_counts_per_rev
        counts_per_period = top_deg_s / 360.0 * cpr * period_s
        assert counts_per_period <= 90.0, j.name  # 200 000 counts/rev: 88.9
        assert DECODER_SAMPLE_HZ * period_s / counts_per_period > 50.0, j.name


def test_a_full_speed_move_sets_no_illegal_transition() -> None:
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=500)
    loop.start()
    LockstepRunner(system, loop).run(500)  # the demo move: every joint up to its top speed
    assert loop.fault is None
    peak = np.nanmax(np.abs(loop.recorder.trimmed()["omega_true"]), axis=0)
    assert math.degrees(float(np.nanmax(peak))) > 10.0  # it did move fast
    for name in ("quad0", "quad1"):
        assert all(ch.stats["illegal"] == 0 for ch in system.crate.board(name).ch)
