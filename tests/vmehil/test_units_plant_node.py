"""The unit bus's coordinator with the plant as the CAN plant node (`vmehil coordinate --plant
can`): the units on the unit bus, the coordinator the node's one controller on the plant bus.
Here over python-can's `virtual` bus (a thread per node, the node a thread of the coordinator's
link); the processes over `udp_multicast`: tests/vmehil/test_units_processes.py."""

from __future__ import annotations

import itertools
import threading

import numpy as np
import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from tests.vmehil.test_units_parallel import BoardProbe, single_run
from tests.vmehil.test_units_remote import UNITS, merged, start_units
from vmehil.option_groups.can_options import CanPlantOptions
from vmehil.unit_controllers.processes import run_coordinator
from vmehil.unit_controllers.remote import unit_bus

_channels = itertools.count()


def plant_node_link(seed: int, channel: str, **kw):
    """A connected link to a fresh plant node thread of every joint on the plant bus ``channel``."""
    return CanPlantOptions(interface="virtual", channel=channel, own_node=True, **kw).open_link("melmalec-16", seed)


@pytest.mark.slow
def test_units_with_the_coordinator_on_the_plant_node_equal_the_single_controller_bit_for_bit() -> None:
    spec = load_rig(resolve_rig("melmalec-16"))
    n = 100
    k = next(_channels)
    results, threads = start_units(spec, f"units-node-eq-{k}")
    link = plant_node_link(5, f"plant-node-eq-{k}")
    node = link.node.node
    bus = unit_bus("virtual", f"units-node-eq-{k}")
    try:
        out = run_coordinator(spec, bus, seed=5, n_ticks=n, timeout_s=5.0, start_timeout_s=20.0, plant_link=link)
    finally:
        bus.close()
    for t in threads:
        t.join(timeout=60)
    # power-up + one per tick, each with every unit in; then each unit's end (a category-1 stop
    # and 2 s watched) while the longest still ticks
    assert out.stop is None and out.exchanges == 1 + max(r.loop.tick_count for r in results.values())
    assert node.counters.steps == out.exchanges + 1  # every exchange, and the last one with every amplifier off
    assert all(r.completed == n and r.loop.fault is None for r in results.values()), results
    ref = single_run(5, n)
    for key in ("theta_true", "omega_true", "theta", "omega", "torque", "current_cmd", "current", "theta_d"):
        assert np.array_equal(ref[key], merged(spec, results, key, n), equal_nan=True), key


@pytest.mark.slow
def test_a_dead_plant_node_safe_stops_every_unit() -> None:
    """The plant node stops answering after exchange 40 (its thread ends: no answer, no
    heartbeat). The coordinator's link gives up after --can-timeout and tells every unit in that
    exchange: every unit safe-stops with the cause plant_lost, its boards off (read back)."""
    spec = load_rig(resolve_rig("melmalec-16"))
    k = next(_channels)
    link = plant_node_link(2, f"plant-node-dead-{k}", can_timeout_s=0.3)
    probe = BoardProbe()
    killed = threading.Event()

    def hook(name, system, loop) -> None:
        probe(name, system, loop)
        if loop.tick_count == 40 and not killed.is_set():
            killed.set()
            link.node.event.set()  # the node thread stops serving: as dead as a killed process

    results, threads = start_units(spec, f"units-node-dead-{k}", timeout_s=10.0, after_tick=hook)
    bus = unit_bus("virtual", f"units-node-dead-{k}")
    try:
        out = run_coordinator(spec, bus, seed=2, n_ticks=300, timeout_s=10.0, start_timeout_s=20.0, plant_link=link)
    finally:
        bus.close()
    for t in threads:
        t.join(timeout=60)
    assert killed.is_set()
    assert out.stop is not None and out.stop.what.startswith("the plant failed"), out.stop
    assert 40 <= out.stop.exchange <= 42  # the exchange that got no answer
    for name in UNITS:
        r = results[name]
        assert not isinstance(r, BaseException), r
        assert r.loop.fault is not None and r.loop.fault.cause == "plant_lost", (name, r.loop.fault)
        assert not r.loop.stop_incomplete
        assert r.completed < 300
        probe(name, r.system, r.loop)  # the boards as the run left them
        assert probe.off[name][r.loop.tick_count - 1] is True, name
        assert probe.off[name][30] is False  # they were on (moving) before


def test_coordinate_refuses_the_unit_bus_as_the_plant_bus(capsys) -> None:
    """Both buses carry CMD/SENS frames: one channel for both is refused before anything opens."""
    from vmehil.cli import main

    code = main(["coordinate", "--rig", "melmalec-16", "--plant", "can", "--interface", "virtual",
                 "--channel", "one-bus", "--plant-channel", "one-bus"])
    assert code == 2
    assert "the plant bus (virtual one-bus) is the unit bus" in capsys.readouterr().err

