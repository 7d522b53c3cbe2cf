"""Real-time settings of a paced run (servo/rt.py): each is applied only when asked, what the
system refuses is reported with its reason, and the run puts everything back; the machine probe
and the runner's per-tick CPU and preemption figures."""

from __future__ import annotations

import os

import pytest

from servo.rt import apply_realtime, machine_probe, wait_until
from servo.runner import RealtimeRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

linux_only = pytest.mark.skipif(not hasattr(os, "sched_setaffinity"), reason="CPU affinity is Linux-only")


def test_nothing_asked_changes_nothing() -> None:
    s = apply_realtime()
    assert s.applied == [] and s.refused == {} and s.describe() == "none"


def test_a_priority_outside_sched_fifo_range_is_refused_before_anything_changes() -> None:
    with pytest.raises(ValueError, match="1..99"):
        apply_realtime(priority=0)


@linux_only
def test_affinity_is_applied_then_restored() -> None:
    before = os.sched_getaffinity(0)
    one = min(before)
    s = apply_realtime(cpus=[one])
    try:
        assert s.applied == [f"CPUs [{one}]"] and os.sched_getaffinity(0) == {one}
    finally:
        s.restore()
    assert os.sched_getaffinity(0) == before


@linux_only
def test_an_affinity_the_system_refuses_is_reported_with_its_reason_and_nothing_changes() -> None:
    before = os.sched_getaffinity(0)
    s = apply_realtime(cpus=[4095])  # no such CPU
    assert "affinity" in s.refused and s.refused["affinity"] and not s.applied
    assert os.sched_getaffinity(0) == before
    assert "affinity refused" in s.describe()


@pytest.mark.skipif(not hasattr(os, "sched_setscheduler"), reason="POSIX scheduling policies")
def test_sched_fifo_is_applied_or_refused_and_the_policy_is_restored_either_way() -> None:
    policy, prio = os.sched_getscheduler(0), os.sched_getparam(0).sched_priority
    s = apply_realtime(priority=1)
    try:
        assert (s.applied == ["SCHED_FIFO priority 1"]) != ("SCHED_FIFO" in s.refused)
        if s.applied:
            assert os.sched_getscheduler(0) == os.SCHED_FIFO
    finally:
        s.restore()
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == (policy, prio)


def test_wait_until_sleeps_then_spins_to_the_deadline_on_an_injected_clock() -> None:
    t = {"now": 0.0}
    slept: list[float] = []

    def clock() -> float:
        t["now"] += 1e-5
        return t["now"]

    def sleep(s: float) -> None:
        slept.append(s)
        t["now"] += s

    wait_until(0.01, clock, sleep, spin_s=0.001)
    assert len(slept) == 1 and slept[0] == pytest.approx(0.009, abs=2e-5)
    assert t["now"] >= 0.01


def test_the_machine_probe_reports_every_figure_for_its_ticks() -> None:
    m = machine_probe(0.04, work_s=0.0002)
    assert m["ticks"] == 5 and m["work_rounds"] >= 1
    assert 0 < m["wall_p50_ms"] <= m["wall_p99_ms"] <= m["wall_max_ms"]
    assert 0 < m["cpu_p50_ms"] <= m["cpu_max_ms"]
    assert 0 <= m["ticks_switched"] <= 5 and 0 <= m["ticks_over_period"] <= 5


def test_the_runner_records_thread_cpu_per_tick_and_restores_what_it_applied() -> None:
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=20)
    loop.start()
    fake = {"t": 0.0}
    cpus = sorted(os.sched_getaffinity(0))[:1] if hasattr(os, "sched_getaffinity") else None
    before = os.sched_getaffinity(0) if cpus else None
    runner = RealtimeRunner(system, loop, clock=lambda: fake["t"], spin_s=0.0,
                            sleep=lambda s: fake.__setitem__("t", fake["t"] + s), cpus=cpus)
    assert runner.run(20) == 20
    s = runner.timing.summary(system.rig.period_s)
    assert runner.timing.compute_cpu_s.total == 20 and s["compute_cpu_p50_ms"] > 0
    assert 0 <= s["ticks_preempted"] <= 20 and s["overruns_preempted"] <= s["overruns"]
    if cpus:
        assert runner.rt_settings is not None and runner.rt_settings.applied == [f"CPUs {cpus}"]
        assert os.sched_getaffinity(0) == before
    system.close()


def test_a_runner_refuses_a_bad_priority_before_any_run() -> None:
    system = build_emulated_rig(None, seed=0)
    loop = build_loop(system, n_ticks=2)
    with pytest.raises(ValueError, match="1..99"):
        RealtimeRunner(system, loop, rt_priority=100)
    system.close()
