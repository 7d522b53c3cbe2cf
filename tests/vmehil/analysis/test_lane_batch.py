"""A batch as one rig of lanes (vmehil.analysis.lane_batch, hal.lanes): every lane followed to the
end equals its scalar run bit for bit; a lane whose scalar run stops (a watchdog trip) is left at
that tick and run again alone; Ctrl-C stops every lane safely and is raised.

The reference of every instance is its scalar run (``SimRun`` ticked by its own runner), an
independent execution of the same inputs; nothing expected comes from the lane code.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

import numpy as np
import pytest

from hal.lanes import LaneSet
from vmehil.analysis.batch import simulate_batch
from vmehil.analysis.lane_batch import LaneReport, simulate_lanes, stack_runs
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimRun, SimSettings, simulate
from vmehil.analysis.sweep import rig_text, task_rig

SIM = SimSettings(move_deg=10, hold_s=0.5, allow_short=True, seed=3)
TRIP_DROP_V = 0.2  #: tach brush drop of the tripping instance (nominal 0.12 V: docs/sweeps.md)


def _instances() -> list[Any]:
    """Four sweep points of joint 1: three gain sets, and a plant whose tach brush drop makes the
    velocity cross-check stop its run (docs/sweeps.md)."""
    text = rig_text("jpl-arm")
    nominal = task_rig(text, "jpl-arm", 1)
    tripping = task_rig(text, "jpl-arm", 1, {"tach_brush_drop": TRIP_DROP_V})
    return [load_joint(nominal, 1, gains={"kp": 80.0}), load_joint(nominal, 1, gains={"kp": 120.0, "kvi": 700.0}),
            load_joint(tripping, 1), load_joint(nominal, 1, gains={"kv": 40.0})]


def _digest(rec: dict[str, np.ndarray]) -> dict[str, str]:
    return {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest() for k, v in rec.items()
            if k != "compute_s"}


def _scalar(jp: Any) -> SimRun:
    run = SimRun(jp, False, SIM)
    with run.loop.armed():
        run.runner.run(run.n_ticks, stop=run.halt_when(None))
    return run


def _run_lanes(runs: list[SimRun], lanes: LaneSet, after_tick: Any = None) -> tuple[Any, Any, Any]:
    rig, loop, runner = stack_runs(runs, lanes)
    runner.after_tick.append(lambda lp: setattr(lanes, "tick", lp.tick_count))
    if after_tick is not None:
        runner.after_tick.append(after_tick)
    with loop.armed():
        runner.run(runs[0].n_ticks, stop=lambda: lanes.n_alive == 0)
    return rig, loop, runner


def test_every_live_lane_equals_its_scalar_run_and_the_tripping_lane_is_left_at_its_trip() -> None:
    jps = _instances()
    runs = [SimRun(jp, False, SIM) for jp in jps]
    lanes = LaneSet(len(runs))
    rig, loop, _runner = _run_lanes(runs, lanes)
    n = rig.rig.n_joints
    truth = rig.truth()
    for b, jp in enumerate(jps):
        ref = _scalar(jp)
        try:
            if b == 2:
                # its scalar run stopped here: the lane was left with that cause, that tick
                assert ref.loop.fault is not None and ref.loop.fault.cause == "velocity_mismatch"
                assert not lanes.alive[b]
                assert lanes.reasons[b].startswith("velocity_mismatch")
                assert lanes.first_tick[b] == ref.loop.fault.tick
                continue
            assert lanes.alive[b] and ref.loop.fault is None
            loop.write_lane(b, runs[b].loop)
            got, want = runs[b].loop.recorder.trimmed(), ref.loop.recorder.trimmed()
            assert _digest(got) == _digest(want), f"lane {b}'s rows differ from its scalar run's"
            assert rig.crate.counter_snapshot() == ref.system.crate.counter_snapshot()
            assert rig.crate.clock.now_ns == ref.system.crate.clock.now_ns
            ref_truth = ref.system.truth()
            for key in ("theta_joint", "omega_joint", "amp_enabled"):
                lane_values = np.asarray(truth[key]).reshape(len(runs), n)[b]
                assert lane_values.tobytes() == np.asarray(ref_truth[key]).tobytes(), key
            assert runs[b].figures(runs[b].summarize(), traces=True) == ref.figures(ref.summarize(), traces=True)
        finally:
            ref.close()


def test_simulate_batch_runs_eight_or_more_as_lanes_with_each_scalar_runs_figures() -> None:
    jps = _instances() * 2  # eight: a batch of lanes (LANES_MIN); lanes 2 and 6 trip and run again alone
    report = LaneReport(len(jps))
    got = simulate_batch([SimRun(jp, False, SIM) for jp in jps], traces=True, report=report)
    assert report.scalar_reason is None and report.vector_ticks > 0
    assert sorted(report.ejected) == [2, 6]
    for g, jp in zip(got, jps, strict=True):
        want = simulate(jp, False, SIM, traces=True)
        assert json.dumps(g, sort_keys=True) == json.dumps(want, sort_keys=True)


def test_a_batch_without_a_lane_form_runs_as_scalar_instances_and_says_why() -> None:
    jps = _instances()[:1] * 8
    runs = [SimRun(jp, False, SIM) for jp in jps[:7]]
    runs.append(SimRun(jps[7], False, SIM, faults=("adc_noise@0.1:joint=j1,rms_v=0.02",)))
    report = LaneReport(len(runs))
    got = simulate_batch(runs, report=report)
    assert report.scalar_reason is not None and "fault" in report.scalar_reason
    assert [g["fault"] for g in got[:7]] == [None] * 7


def test_ctrl_c_in_lanes_stops_every_lane_safely_and_is_raised() -> None:
    jps = _instances()[:2] * 2
    runs = [SimRun(jp, False, SIM) for jp in jps]
    lanes = LaneSet(len(runs))

    def interrupt(lp: Any) -> None:  # a SIGINT arriving at tick 40
        if lp.tick_count == 40:
            raise KeyboardInterrupt

    rig, loop, runner = _run_lanes(runs, lanes, interrupt)
    assert isinstance(runner.ended_by, KeyboardInterrupt)
    assert loop.tick_count < runs[0].n_ticks
    # what the boards drive into the amplifiers after the stop, every lane (the harness reads the nets)
    cmd = rig.harness.collect()
    assert not np.asarray(cmd.amp_enable).any()
    assert np.all(np.abs(np.asarray(cmd.amp_command_v)) <= 0.01)  # 0 V less the DAC's offset (≤ 10 mV)
    assert np.all(np.asarray(cmd.pwm_duty) == 0.0)
    latest = rig.harness.pending if rig.harness.pending is not None else rig.harness.last
    assert latest is not None and not np.asarray(latest.truth["amp_enabled"]).any()


def test_simulate_lanes_raises_the_interrupt_after_the_stop() -> None:
    runs = [SimRun(jp, False, SIM) for jp in _instances()[:2] * 4]
    calls = {"n": 0}

    def stop() -> bool:
        calls["n"] += 1
        if calls["n"] == 30:
            raise KeyboardInterrupt
        return False

    with pytest.raises(KeyboardInterrupt):
        simulate_lanes(runs, stop=stop)


def test_instances_with_faults_run_scalar_beside_the_lanes_of_the_others() -> None:
    jps = _instances()[:2] * 4  # eight without faults: lanes; two more with their own faults: scalar
    faults = ("adc_noise@0.1:joint=j1,rms_v=0.02",)
    runs = [SimRun(jp, False, SIM) for jp in jps]
    runs[3:3] = [SimRun(jps[0], False, SIM, faults=faults), SimRun(jps[1], False, SIM, faults=faults)]
    report = LaneReport(len(runs))
    got = simulate_batch(runs, report=report)
    assert report.vector_ticks > 0 and "injected faults" in str(report.scalar_reason)
    want = [simulate(jp, False, SIM, traces=False) for jp in jps[:3]]
    faulted = SimRun(jps[0], False, SIM, faults=faults)
    with faulted.loop.armed():
        faulted.runner.run(faulted.n_ticks, stop=faulted.halt_when(None))
    want_faulted = faulted.figures(faulted.summarize(), traces=False)
    faulted.close()
    assert [json.dumps(g, sort_keys=True) for g in got[:3]] == [json.dumps(w, sort_keys=True) for w in want]
    assert json.dumps(got[3], sort_keys=True) == json.dumps(want_faulted, sort_keys=True)
