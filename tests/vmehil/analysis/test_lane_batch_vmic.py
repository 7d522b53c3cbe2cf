"""jpl-arm-vmic as one rig of lanes (issue #34): the commercial boards (VMIVME-3113A ADC,
VMIVME-4116 DAC, VMIVME-2536 digital I/O, the idle SBS 617 vision link) beside the reference PIO
and decoders, eight sweep points of joint 1 run by ``simulate_batch`` as lanes, each equal to its
own scalar ``simulate()`` — figures with traces, bit for bit — and the one whose tach brush drop
trips the velocity cross-check left at its trip and run again alone.

The reference of every instance is its scalar run, an independent execution of the same inputs;
nothing expected comes from the lane code.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from vmehil.analysis.batch import simulate_batch
from vmehil.analysis.lane_batch import LaneReport
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimRun, SimSettings, simulate
from vmehil.analysis.sweep import rig_text, task_rig

PRESET = "jpl-arm-vmic"
SIM = SimSettings(move_deg=10, hold_s=0.5, allow_short=True, seed=3)
TRIP_DROP_V = 0.2  #: tach brush drop of the tripping instance (nominal 0.12 V: docs/sweeps.md)
TRIPPING = 5  #: the instance whose run stops (its velocity cross-check trips)


def _instances() -> list[Any]:
    """Eight sweep points of joint 1: seven gain sets (the rig's and six others), and at
    :data:`TRIPPING` the rig's gains on a plant whose tach brush drop makes the velocity
    cross-check stop its run (as tests/vmehil/analysis/test_lane_batch.py)."""
    text = rig_text(PRESET)
    nominal = task_rig(text, PRESET, 1)
    tripping = task_rig(text, PRESET, 1, {"tach_brush_drop": TRIP_DROP_V})
    gains: list[dict[str, float]] = [{"kp": 80.0}, {"kp": 120.0, "kvi": 700.0}, {"kv": 40.0}, {},
                                     {"kp": 90.0, "kv": 60.0}, {"kv": 55.0, "kvi": 1200.0}, {"kpi": 4000.0}]
    jps = [load_joint(nominal, 1, gains=g) for g in gains]
    jps.insert(TRIPPING, load_joint(tripping, 1))
    return jps


@pytest.mark.slow  # ≈ 3 s: eight lanes, then their eight scalar references
def test_eight_jpl_arm_vmic_instances_as_lanes_equal_their_scalar_runs_bit_for_bit() -> None:
    jps = _instances()
    report = LaneReport(len(jps))
    got = simulate_batch([SimRun(jp, False, SIM) for jp in jps], traces=True, report=report)
    assert report.scalar_reason is None and report.vector_ticks > 0
    assert sorted(report.ejected) == [TRIPPING]
    assert report.ejected[TRIPPING].startswith("velocity_mismatch")
    for b, (g, jp) in enumerate(zip(got, jps, strict=True)):
        want = simulate(jp, False, SIM, traces=True)
        assert json.dumps(g, sort_keys=True) == json.dumps(want, sort_keys=True), f"instance {b}"
        assert (want["fault"] is not None and want["fault"]["cause"] == "velocity_mismatch") == (b == TRIPPING)
