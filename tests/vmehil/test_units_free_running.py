"""Free-running units (`vmehil coordinate --plant-mode free-running`): every unit on its own
125 Hz wall clock, the coordinator stepping the plant on its own with each unit's newest
commands. Over python-can's `virtual` bus, a thread per node.

These tests never race the wall clock: whether the units keep up with 125 Hz depends on the
machine's load, so they assert only what must hold on any machine — the run ends (never a
hang), with a stated cause, every unit's boards and the plant's amplifiers off."""

from __future__ import annotations

import itertools
import threading

from emulators.presets import resolve_rig
from servo.rig import load_rig
from tests.vmehil.test_units_parallel import BoardProbe
from tests.vmehil.test_units_remote import UNITS, start_units
from vmehil.unit_controllers.processes import run_coordinator
from vmehil.unit_controllers.remote import unit_bus

_channels = itertools.count()


def run_free(n_ticks: int, *, after_tick=None, stale_ticks: int = 5, timeout_s: float = 10.0):
    spec = load_rig(resolve_rig("melmalec-16"))
    channel = f"units-free-{next(_channels)}"
    results, threads = start_units(spec, channel, timeout_s=timeout_s, start_timeout_s=30.0,
                                   realtime_options={"overrun": "warn"}, after_tick=after_tick)
    bus = unit_bus("virtual", channel)
    try:
        out = run_coordinator(spec, bus, seed=1, n_ticks=n_ticks, timeout_s=timeout_s, start_timeout_s=30.0,
                              free_running=True, stale_ticks=stale_ticks)
    finally:
        bus.close()
    return out, results, threads


def assert_off(probe: BoardProbe, name: str, r) -> None:
    """The unit's run ended and left its boards off (enables low, DACs 0 V, PWM 0: read from
    the boards), its final stop read back."""
    assert not isinstance(r, BaseException), (name, r)
    assert not r.loop.stop_incomplete, name
    probe(name, r.system, r.loop)
    assert probe.off[name][r.loop.tick_count - 1] is True, name


def test_free_running_units_end_with_a_stated_cause_and_every_amplifier_off() -> None:
    """Whatever the load: every unit either ran its ticks or stopped with a cause (a lost
    answer, a lost unit, a watchdog check); the run ends; every board and the plant end off;
    each unit reported its real-time figures to the coordinator."""
    out, results, threads = run_free(60)
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    probe = BoardProbe()
    for name in UNITS:
        r = results[name]
        assert_off(probe, name, r)
        assert r.completed == 60 or (r.loop.fault is not None and r.loop.fault.cause), (name, r.loop.fault)
    assert out.amps_on[-1] == 0  # the plant's amplifiers: every one off at the end
    assert (out.stop is None) == all(results[n].completed == 60 and results[n].loop.fault is None for n in UNITS)
    assert set(out.unit_timing) == set(UNITS)
    for name, fig in out.unit_timing.items():
        assert fig["realtime"] is True and fig["ticks"] == results[name].completed
        assert fig["compute_max_ms"] >= fig["compute_p50_ms"] > 0.0
        assert fig["overruns"] <= fig["ticks"]
    figures = out.timing.figures(0.008)
    assert figures["steps"] == out.exchanges and figures["ticks"] == out.exchanges - 1  # the power-up is lockstep
    assert figures["plant_p50_ms"] > 0.0 and figures["overruns"] <= figures["ticks"]


def test_a_hung_unit_is_declared_lost_and_every_amplifier_ends_off() -> None:
    """leg3 stops talking after its first tick (its thread hangs: as silent as a killed
    process). The coordinator declares it lost (no commands for more than --stale-ticks
    periods), steps the plant with leg3's amplifiers off and tells every other unit to stop;
    the run ends with every board of the others and every amplifier of the plant off. Released,
    leg3 ends safe-stopped too."""
    release = threading.Event()

    def hang(name, system, loop) -> None:
        if name == "leg3" and loop.tick_count == 1:
            release.wait(120)

    out, results, threads = run_free(500, after_tick=hang, stale_ticks=5, timeout_s=10.0)
    try:
        lost = [e for e in out.events if e.unit == "leg3" and e.what.startswith("lost")]
        assert lost, out.events
        # from the step that declared it lost, the plant steps with leg3's 3 amplifiers off
        assert all(on <= 13 for on in out.amps_on[lost[0].exchange:]), out.amps_on
        assert out.amps_on[-1] == 0
        assert out.stop is not None and out.stop.what  # the run ended with a stated cause
        probe = BoardProbe()
        for name in UNITS:
            if name == "leg3":
                continue
            threads[UNITS.index(name)].join(timeout=60)
            assert_off(probe, name, results[name])
            assert results[name].loop.fault is not None
    finally:
        release.set()
    threads[UNITS.index("leg3")].join(timeout=60)
    assert_off(BoardProbe(), "leg3", results["leg3"])
    assert results["leg3"].loop.fault is not None  # no answer after the coordinator ended: a safe stop
