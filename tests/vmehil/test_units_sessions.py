"""The unit bus checks every frame's boot id against the session's (docs/melmalec.md,
"Sessions"): a forged UNIT_SYNC, UNIT_STOP or UNIT_START of a boot id nobody in the run has is
dropped and counted, and the run goes on (or, with no coordinator, never starts); two units of
one name are refused before the run starts. Over python-can's `virtual` bus, a thread per node
(tests/vmehil/test_units_remote.py)."""

from __future__ import annotations

import itertools
import threading

import pytest

from emulators.can.dbc import UNIT_STOP_CAUSES
from emulators.presets import resolve_rig
from servo.rig import load_rig
from tests.vmehil.test_units_remote import UNITS, start_units
from vmehil.unit_controllers.processes import run_coordinator
from vmehil.unit_controllers.remote import ALL_UNITS, UnitRefused, unit_bus

pytestmark = pytest.mark.slow  # five unit controllers and a coordinator: 3-6 s each

N_TICKS = 40
FORGED_BOOT = 0xBEEF  # a boot id nobody in the run has (each node's is drawn at its start)
STOP = {name: code for code, name in UNIT_STOP_CAUSES.items()}
_channels = itertools.count()


def _session(spec, channel: str, forge) -> tuple[dict, object]:
    """Five units and a coordinator on ``channel``; ``forge(bus)`` is called once from leg1's
    tick 20, on a bus of its own (the forger's). Returns the units' results and the coordinator's
    outcome."""
    forger = unit_bus("virtual", channel)
    sent = threading.Event()

    def hook(name, system, loop) -> None:
        if name == "leg1" and loop.tick_count == 20 and not sent.is_set():
            forge(forger)
            sent.set()

    results, threads = start_units(spec, channel, after_tick=hook)
    bus = unit_bus("virtual", channel)
    try:
        out = run_coordinator(spec, bus, seed=0, n_ticks=N_TICKS, timeout_s=5.0, start_timeout_s=20.0)
    finally:
        bus.close()
        for t in threads:
            t.join(timeout=60)
        forger.close()
    assert sent.is_set()
    return results, out


@pytest.fixture(scope="module")
def spec():
    return load_rig(resolve_rig("melmalec-16"))


def test_a_forged_unit_sync_saying_a_unit_left_is_dropped_and_the_run_goes_on(spec) -> None:
    def forge(bus) -> None:
        bus.send("UNIT_SYNC", Exchange=0xFFFFFFFF, Unit=2, Left=1, Stopped=0, BootId=FORGED_BOOT)

    results, out = _session(spec, f"units-forged-sync-{next(_channels)}", forge)
    assert out.stop is None, out.stop
    assert out.other_session >= 1
    assert all(r.completed == N_TICKS and r.loop.fault is None for r in results.values()), results


def test_a_forged_unit_stop_stops_no_unit(spec) -> None:
    def forge(bus) -> None:
        for cause in ("COORDINATOR_END", "UNIT_STOPPED"):
            bus.send("UNIT_STOP", Cause=STOP[cause], Unit=ALL_UNITS, Exchange=21, BootId=FORGED_BOOT)

    results, out = _session(spec, f"units-forged-stop-{next(_channels)}", forge)
    assert out.stop is None, out.stop
    assert all(r.completed == N_TICKS and r.loop.fault is None for r in results.values()), results


def test_a_forged_unit_start_starts_no_unit_without_a_coordinator(spec) -> None:
    channel = f"units-forged-start-{next(_channels)}"
    listener = unit_bus("virtual", channel)
    results, threads = start_units(spec, channel, start_timeout_s=1.5)
    try:
        beat = None
        while beat is None:  # copy a waiting unit's heartbeat's digest
            f = listener.recv(20.0)
            assert f is not None, "no unit reported"
            if f.kind == "UNIT_HEARTBEAT":
                beat = f
        for u in range(len(UNITS)):
            listener.send("UNIT_START", Seed=0, NTicks=N_TICKS, RigDigest=int(beat.raw["RigDigest"]), NUnits=5,
                          BootId=FORGED_BOOT, Unit=u, UnitBootId=0)
    finally:
        for t in threads:
            t.join(timeout=60)
        listener.close()
    for name in UNITS:
        r = results[name]
        assert isinstance(r, UnitRefused) and "no coordinator" in str(r), (name, r)


def test_two_units_of_one_name_are_refused_and_the_run_does_not_start(spec) -> None:
    channel = f"units-twice-{next(_channels)}"
    results, threads = start_units(spec, channel)
    second, second_threads = start_units(spec, channel, names=("leg2",))
    bus = unit_bus("virtual", channel)
    try:
        with pytest.raises(UnitRefused, match="2 units leg2"):
            run_coordinator(spec, bus, seed=0, n_ticks=N_TICKS, timeout_s=5.0, start_timeout_s=20.0)
    finally:
        bus.close()
        for t in threads + second_threads:
            t.join(timeout=60)
    assert isinstance(second["leg2"], UnitRefused) and "same name" in str(second["leg2"])
    assert isinstance(results["leg2"], UnitRefused) and "same name" in str(results["leg2"])
    for name in ("leg1", "leg3", "leg4", "arm"):
        assert isinstance(results[name], UnitRefused) and "refused the run" in str(results[name]), name
