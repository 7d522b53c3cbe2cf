"""The unit bus (vmehil.unit_controllers.remote): the unit controllers and the coordinator as separate
nodes on CAN. Here over python-can's `virtual` bus with one thread per node (the same code the
`vmehil unit` / `vmehil coordinate` processes run); the processes themselves over
`udp_multicast`: tests/vmehil/test_units_processes.py."""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

from emulators.can.bus import socketcan_available
from emulators.presets import resolve_rig
from servo.joint_groups import rig_units
from servo.rig import load_rig
from vmehil.unit_controllers.processes import run_coordinator, run_unit
from vmehil.unit_controllers.remote import UnitRefused, unit_bus

UNITS = ("leg1", "leg2", "leg3", "leg4", "arm")
_channels = itertools.count()


def start_units(spec, channel: str, names=UNITS, per_unit: dict | None = None,
                **kw) -> tuple[dict, list[threading.Thread]]:
    """A thread per unit on the `virtual` unit bus ``channel``; ``kw``: run_unit's options
    (timeout_s 5, start_timeout_s 20 unless given), ``per_unit``: more for some units (name →
    options). The results: a UnitRun or the exception."""
    results: dict = {}
    opts = {"timeout_s": 5.0, "start_timeout_s": 20.0, **kw}

    def unit(name: str) -> None:
        bus = unit_bus("virtual", channel)
        try:
            results[name] = run_unit(spec, name, bus, **opts, **(per_unit or {}).get(name, {}))
        except BaseException as e:  # the test reads it
            results[name] = e
        finally:
            bus.close()

    threads = [threading.Thread(target=unit, args=(n,), daemon=True) for n in names]
    for t in threads:
        t.start()
    return results, threads


def merged(spec, results: dict, key: str, rows: int) -> np.ndarray:
    units = {u.name: u for u in rig_units(spec)}
    out = np.full((rows, spec.n_joints), np.nan)
    for name, o in results.items():
        out[:, list(units[name].indices)] = o.loop.recorder.trimmed()[key]
    return out


@pytest.mark.slow
def test_units_on_the_unit_bus_equal_the_single_controller_bit_for_bit() -> None:
    from tests.vmehil.test_units_parallel import single_run

    spec = load_rig(resolve_rig("melmalec-16"))
    n = 120
    channel = f"units-eq-{next(_channels)}"
    results, threads = start_units(spec, channel)
    bus = unit_bus("virtual", channel)
    try:
        out = run_coordinator(spec, bus, seed=3, n_ticks=n, timeout_s=5.0, start_timeout_s=20.0)
    finally:
        bus.close()
    for t in threads:
        t.join(timeout=60)
    # power-up + one per tick, each with every unit in; then each unit's end (a category-1 stop
    # and 2 s watched) while the longest still ticks
    assert out.stop is None and out.exchanges == 1 + max(r.loop.tick_count for r in results.values())
    assert all(r.completed == n and r.loop.fault is None for r in results.values()), results
    ref = single_run(3, n)
    for key in ("theta_true", "omega_true", "theta", "omega", "torque", "current_cmd", "current", "theta_d"):
        assert np.array_equal(ref[key], merged(spec, results, key, n), equal_nan=True), key


@pytest.mark.slow
def test_a_unit_with_another_rig_file_is_refused_and_the_run_does_not_start(tmp_path) -> None:
    spec = load_rig(resolve_rig("melmalec-16"))
    other = tmp_path / "melmalec-16.toml"
    other.write_text(spec.path.read_text() + "\n# edited\n")
    other_spec = load_rig(other)
    channel = f"units-rig-{next(_channels)}"
    results, threads = start_units(spec, channel, names=UNITS[:4], start_timeout_s=3.0)
    odd, odd_threads = start_units(other_spec, channel, names=("arm",))
    bus = unit_bus("virtual", channel)
    try:
        with pytest.raises(UnitRefused, match="units arm did not report"):
            run_coordinator(spec, bus, seed=0, n_ticks=10, timeout_s=2.0, start_timeout_s=1.0)
    finally:
        bus.close()
    for t in odd_threads:
        t.join(timeout=30)
    assert isinstance(odd["arm"], UnitRefused) and "rig file differs" in str(odd["arm"])
    for t in threads:  # the others were never started: they give up after their start timeout
        t.join(timeout=60)
    assert all(isinstance(r, UnitRefused) for r in results.values())


@pytest.mark.slow
def test_a_unit_started_after_the_run_began_is_refused() -> None:
    spec = load_rig(resolve_rig("melmalec-16"))
    channel = f"units-late-{next(_channels)}"
    results, threads = start_units(spec, channel)
    bus = unit_bus("virtual", channel)
    late: dict = {}
    done = threading.Event()

    def coordinator() -> None:
        try:
            late["out"] = run_coordinator(spec, bus, seed=0, n_ticks=100, timeout_s=5.0, start_timeout_s=20.0)
        finally:
            done.set()

    watch = unit_bus("virtual", channel)  # a listener: the run has started at its first answer
    c = threading.Thread(target=coordinator, daemon=True)
    c.start()
    try:
        while True:
            f = watch.recv(60.0)
            assert f is not None, "the run did not start"
            if f.kind == "UNIT_ANSWER":
                break
    finally:
        watch.close()
    late_results, late_threads = start_units(spec, channel, names=("leg1",), start_timeout_s=10.0)
    for t in late_threads:
        t.join(timeout=60)
    c.join(timeout=120)
    for t in threads:
        t.join(timeout=60)
    bus.close()
    assert isinstance(late_results["leg1"], UnitRefused) and "already started" in str(late_results["leg1"])
    assert any("after the start" in note for note in late["out"].refused)
    assert all(r.completed == 100 and r.loop.fault is None for r in results.values())  # the run went on


@pytest.mark.skipif(socketcan_available(), reason="SocketCAN exists here: the refusal path is not what runs")
def test_the_unit_bus_on_socketcan_without_socketcan_is_a_clear_error() -> None:
    from emulators.can.bus import BusConfigError

    with pytest.raises(BusConfigError, match="socketcan"):
        unit_bus("socketcan", None)
