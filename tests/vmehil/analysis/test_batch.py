"""Batched lockstep (vmehil.analysis.batch): B full-stack runs ticked together in one process.

The reference for every instance is the scalar run of the same inputs (an independent path: the
runner's own ``run(n)`` over the whole run); the batch must reproduce it byte for byte. The
tripping instance is the finding of docs/sweeps.md: a tach brush drop beyond the controller's
nominal one makes the watchdog's velocity cross-check stop the run (``velocity_mismatch``).
"""

from __future__ import annotations

import hashlib

import numpy as np
import pytest

from vmehil.analysis import batch as batch_mod
from vmehil.analysis.batch import BatchError, choose_batch, parse_batch, run_lockstep, simulate_batch
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimRun, SimSettings
from vmehil.analysis.sweep import SweepTask, evaluate_batch, evaluate_point, rig_text, task_rig

SIM = SimSettings(move_deg=10, hold_s=0.5, allow_short=True, seed=3)
TRIP_DROP_V = 0.2  #: tach brush drop of the tripping instance (nominal 0.12 V: docs/sweeps.md)


#: the fourth instance's own faults (docs/faults.md): noise on its pot's ADC input, counts its decoder misses
FAULTS = ("adc_noise@0.1:joint=j1,rms_v=0.02", "encoder_missed@0.2:joint=j1,counts=30")


def _instances():
    text = rig_text("jpl-arm")
    nominal = task_rig(text, "jpl-arm", 1)
    tripping = task_rig(text, "jpl-arm", 1, {"tach_brush_drop": TRIP_DROP_V})
    return [load_joint(nominal, 1, gains={"kp": 80.0}), load_joint(nominal, 1, gains={"kp": 120.0, "kvi": 700.0}),
            load_joint(tripping, 1), load_joint(nominal, 1, gains={"kv": 40.0})]


def _run(i: int, jp) -> SimRun:
    return SimRun(jp, False, SIM, faults=FAULTS if i == 3 else ())


def _fingerprint(run: SimRun) -> dict:
    loop = run.loop
    rec = loop.recorder.trimmed()
    out = {k: hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest() for k, v in rec.items()
           if k != "compute_s"}
    out["ticks"] = loop.tick_count
    out["fault"] = None if loop.fault is None else loop.fault.as_dict()
    out["log"] = repr(loop.log)
    out["counters"] = run.system.crate.counter_snapshot()
    out["clock_ns"] = run.system.crate.clock.now_ns
    out["truth"] = {k: np.asarray(v).tobytes() for k, v in (run.system.truth() or {}).items()}
    return out


def _scalar(i: int, jp) -> SimRun:
    run = _run(i, jp)
    with run.loop.armed():
        run.runner.run(run.n_ticks, stop=run.halt_when(None))
    return run


def _assert_safe_stopped(run: SimRun, *, plant: bool = True) -> None:
    """What the boards drive into the amplifiers, and (``plant``) the plant's truth after the
    stop's exchange, once the run stopped."""
    cmd = run.system.harness.collect()
    assert not cmd.amp_enable.any()
    assert np.all(np.abs(cmd.amp_command_v) <= 0.01)  # 0 V less the DAC's output offset (rig file: ≤ 10 mV)
    assert np.all(cmd.pwm_duty == 0.0)
    if not plant:
        return
    h = run.system.harness
    latest = h.pending if h.pending is not None else h.last  # the plant's answer to the stop's exchange
    assert latest is not None and not latest.truth["amp_enabled"].any()


@pytest.mark.slow  # over 1.5 s (8 runs): make test (CI) runs it, make test-fast leaves it out
def test_each_instance_of_a_batch_of_four_equals_its_scalar_run_and_a_trip_stops_only_its_own() -> None:
    jps = _instances()
    batch = [_run(i, jp) for i, jp in enumerate(jps)]
    try:
        ticks = run_lockstep(batch, window=1)  # every tick interleaved: the strictest order
        got = [_fingerprint(r) for r in batch]
        # the tripping instance is safe-stopped (its boards and its plant), the others ran every tick
        _assert_safe_stopped(batch[2])
        assert ticks.per_instance == [r.loop.tick_count for r in batch]
        assert ticks.per_instance[2] < ticks.per_instance[0] == batch[0].n_ticks
    finally:
        for r in batch:
            r.close()
    assert got[2]["fault"]["cause"] == "velocity_mismatch"
    for i in (0, 1):
        assert got[i]["fault"] is None
    assert "injected adc_noise" in got[3]["log"] and "injected encoder_missed" in got[3]["log"]
    assert "injected" not in got[0]["log"]  # the faults are the fourth instance's alone
    for i, jp in enumerate(jps):
        ref = _scalar(i, jp)
        try:
            assert got[i] == _fingerprint(ref), f"instance {i} differs from its scalar run"
        finally:
            ref.close()


def test_ctrl_c_during_a_batch_safe_stops_every_instance_and_is_raised() -> None:
    jps = _instances()[:2]
    batch = [SimRun(jp, False, SIM) for jp in jps]
    calls = {"n": 0}

    def stop() -> bool:  # a SIGINT arriving while the batch polls its stop (tick 10)
        calls["n"] += 1
        if calls["n"] == 20:
            raise KeyboardInterrupt
        return False

    try:
        with pytest.raises(KeyboardInterrupt):
            run_lockstep(batch, stop=stop)
        for r in batch:
            assert r.loop.fault is not None and r.loop.fault.cause == "interrupted"
            _assert_safe_stopped(r)
            assert r.loop.tick_count < r.n_ticks
    finally:
        for r in batch:
            r.close()


def test_a_stop_request_ends_every_instance_through_its_safe_stop() -> None:
    jps = _instances()[:2]
    batch = [SimRun(jp, False, SIM) for jp in jps]
    windows: list[int] = []

    def stop() -> bool:  # once every instance has run 15 ticks
        return min(r.loop.tick_count for r in batch) >= 15

    figures = simulate_batch(batch, stop=stop, progress=lambda k, n: windows.append(k), window=25,
                             lanes=False)  # the form of scalar instances: windows of 25 ticks
    assert len(figures) == 2
    # instance 0 ran its first window of 25 ticks; instance 1 stopped at 15, then instance 0 at once
    assert [r.loop.tick_count for r in batch] == [25, 15]
    assert windows == [25, 50]
    for r in batch:
        # as a scalar run told to stop: the loop's shutdown leaves the boards safe; no exchange follows
        _assert_safe_stopped(r, plant=False)


def test_batched_sweep_rows_equal_the_scalar_rows_but_wall_time() -> None:
    text = rig_text("jpl-arm")
    rig = task_rig(text, "jpl-arm", 1)
    jp = load_joint(rig, 1)
    sim = SimSettings(move_deg=2, hold_s=0.3, allow_short=True)
    gains = [{**jp.cfg.gains.as_dict(), "kp": kp} for kp in (80.0, 110.0)]
    tasks = [SweepTask(i, "jpl-arm", 1, g, sim, rig=rig, servo=jp.servo) for i, g in enumerate(gains)]
    tasks.append(SweepTask(2, "jpl-arm", 1, gains[0], sim, rig=rig, servo=jp.servo, simulate=False))
    batched = evaluate_batch(tasks)
    scalar = [evaluate_point(t) for t in tasks]
    strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert strip(batched) == strip(scalar)
    assert [r["status"] for r in batched] == ["ok", "ok", "margins only"]


def test_batch_size_parsing_and_auto_choice() -> None:
    assert parse_batch("auto") is None
    assert parse_batch("8") == 8
    for bad in ("0", "x", "-3"):
        with pytest.raises(BatchError):
            parse_batch(bad)
    rig = task_rig(rig_text("jpl-arm"), "jpl-arm", 1)
    # 400 points on 2 workers, plenty of memory: 4 batches of 50 each; 4 000 points: capped at 256;
    # 40 points: 20 each (4 batches would be 5 lanes each, below 32)
    assert choose_batch(None, 400, 2, rig, memory_mib=64_000) == (50, None)
    assert choose_batch(None, 4000, 2, rig, memory_mib=64_000) == (256, None)
    assert choose_batch(None, 40, 2, rig, memory_mib=64_000) == (20, None)
    # 10 points on 2 workers: 5 each keeps both busy
    assert choose_batch(None, 10, 2, rig, memory_mib=64_000) == (5, None)
    # 80 MiB free: half of it at 4 MiB an instance, over 2 workers = 5
    assert choose_batch(None, 400, 2, rig, memory_mib=80) == (5, None)
    assert choose_batch(7, 400, 2, rig) == (7, None)


def test_a_rig_with_a_plugin_board_type_is_refused_by_batch_n_and_runs_scalar_under_auto(monkeypatch) -> None:
    rig = task_rig(rig_text("jpl-arm"), "jpl-arm", 1)
    # stand-in for a plug-in board type: the rig's decoder type is not among the batchable ones
    monkeypatch.setattr(batch_mod, "batchable_types", lambda: frozenset({"adc", "dac", "pio", "bit3", "ram"}))
    assert batch_mod.batch_blockers(rig) == ["quad"]
    with pytest.raises(BatchError, match=r"--batch 4: rig jpl-arm has board type\(s\) quad from a plug-in"):
        choose_batch(4, 10, 2, rig)
    size, note = choose_batch(None, 10, 2, rig)
    assert size == 1 and note is not None and "running one at a time" in note
    assert choose_batch(1, 10, 2, rig) == (1, None)
