"""`vmehil unit` ×5 and `vmehil coordinate` as separate processes over udp_multicast (only inside
a private network namespace: `make test`, or the unshare line of RULES.md)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys

import numpy as np
import pytest

from emulators.can.bus import private_multicast_namespace
from emulators.presets import resolve_rig
from servo.joint_groups import rig_units
from servo.rig import load_rig

pytestmark = pytest.mark.skipif(not private_multicast_namespace(),
                                reason="udp_multicast only inside a private namespace")

UNITS = ("leg1", "leg2", "leg3", "leg4", "arm")


def vmehil(*args: str) -> list[str]:
    return [sys.executable, "-m", "vmehil", *args]


def start_units(tmp_path, *extra: str) -> dict[str, subprocess.Popen]:
    return {name: subprocess.Popen(vmehil("unit", "--rig", "melmalec-16", "--unit", name,
                                          "--interface", "udp_multicast", "--start-timeout", "120",
                                          "--json", str(tmp_path / f"{name}.json"),
                                          "--record", str(tmp_path / f"{name}.npz"), *extra),
                                   stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            for name in UNITS}


def wait_all(procs: dict[str, subprocess.Popen], timeout: float = 300.0) -> dict[str, int]:
    codes = {}
    for name, p in procs.items():
        try:
            p.wait(timeout=timeout)
        finally:
            if p.poll() is None:
                p.kill()
        codes[name] = p.returncode
    return codes


def assert_recorded_equal_single(tmp_path, seed: int, n_ticks: int) -> None:
    """Every unit's recorded arrays (--record), merged in joint order, equal the single
    controller's for the same seed, bit for bit."""
    from tests.vmehil.test_units_parallel import single_run

    spec = load_rig(resolve_rig("melmalec-16"))
    ref = single_run(seed, n_ticks)
    for key in ("theta_true", "omega_true", "theta", "omega", "torque", "current_cmd", "current", "theta_d"):
        got = np.full_like(ref[key], np.nan)
        for u in rig_units(spec):
            got[:, list(u.indices)] = np.load(tmp_path / f"{u.name}.npz")[key]
        assert np.array_equal(ref[key], got, equal_nan=True), key


def assert_units_ended_by_category_1(tmp_path, n_ticks: int) -> None:
    """Every unit's JSON (--json): its run's ticks, then the single run's end — a category-1
    stop for the run's end, verified, each of its joints' excursion over it and the 2 s after."""
    spec = load_rig(resolve_rig("melmalec-16"))
    for u in rig_units(spec):
        summary = json.loads((tmp_path / f"{u.name}.json").read_text())
        stop = summary["final_stop"]
        assert summary["ticks"] == n_ticks and summary["faults"] == [], u.name
        assert stop["category"] == 1 and stop["cause"] == "end" and stop["verified"], u.name
        assert stop["tick"] >= n_ticks + 250  # the stop, then 2 s watched
        for key in ("excursion_deg", "excursion_sensor_deg"):
            assert list(stop[key]) == list(u.joints), u.name
        braked = [j for j in u.joints if j.endswith(("_lift", "_knee"))]
        assert all(stop["excursion_deg"][j] < 1.0 for j in braked), stop["excursion_deg"]


def kill_leg3_at(exchange: int, coord: subprocess.Popen, units: dict[str, subprocess.Popen]) -> dict[str, int]:
    """SIGKILL leg3 once the coordinator has answered ``exchange``; every process's exit code."""
    try:
        wait_for_exchange(exchange)
        os.kill(units["leg3"].pid, signal.SIGKILL)
        coord.wait(timeout=300)
        codes = wait_all(units)
    finally:
        for p in (coord, *units.values()):
            if p.poll() is None:
                p.kill()
    assert codes["leg3"] == -signal.SIGKILL
    return codes


def wait_for_exchange(at_least: int) -> None:
    """Listen on the unit bus until the coordinator has answered exchange ``at_least``."""
    from vmehil.unit_controllers.remote import unit_bus

    bus = unit_bus("udp_multicast", None)
    try:
        while True:
            f = bus.recv(120.0)
            assert f is not None, "the run did not reach that exchange"
            if f.kind == "UNIT_ANSWER" and int(f.raw["Exchange"]) >= at_least:
                return
    finally:
        bus.close()


@pytest.mark.slow
def test_unit_processes_in_lockstep_equal_the_single_controller_bit_for_bit(tmp_path) -> None:
    units = start_units(tmp_path)
    coord = subprocess.run(vmehil("coordinate", "--rig", "melmalec-16", "--seed", "3", "--duration", "1",
                                  "--interface", "udp_multicast", "--start-timeout", "120",
                                  "--json", str(tmp_path / "coordinator.json")),
                           capture_output=True, text=True, timeout=600)
    assert coord.returncode == 0, coord.stderr
    assert set(wait_all(units).values()) == {0}
    summary = json.loads((tmp_path / "coordinator.json").read_text())
    # the run's 125 ticks and the power-up, then each unit's end (a category-1 stop, 2 s watched)
    assert summary["stop"] is None and summary["plant_steps"] >= 126 + 250
    assert_recorded_equal_single(tmp_path, 3, 125)
    assert_units_ended_by_category_1(tmp_path, 125)


@pytest.mark.slow
def test_a_killed_unit_process_stops_every_unit_and_its_amplifiers(tmp_path) -> None:
    """SIGKILL leg3 mid-move: the coordinator declares it lost at the exchange it missed (after
    --unit-timeout), the plant steps with leg3's amplifiers off, every other unit safe-stops in
    that tick (read back from its boards) and the plant ends with every amplifier off."""
    units = start_units(tmp_path, "--unit-timeout", "10")
    coord = subprocess.Popen(vmehil("coordinate", "--rig", "melmalec-16", "--seed", "1", "--duration", "60",
                                    "--interface", "udp_multicast", "--start-timeout", "120", "--unit-timeout", "5",
                                    "--json", str(tmp_path / "coordinator.json")),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    codes = kill_leg3_at(50, coord, units)  # every amplifier is on by exchange 50
    summary = json.loads((tmp_path / "coordinator.json").read_text())
    stop = summary["stop"]
    assert stop["unit"] == "leg3" and stop["what"].startswith("lost")
    lost_at = stop["exchange"]
    on = summary["amps_on"]  # per plant step: 0 power-up, k + 1 after tick k; the last: all idle
    assert on[lost_at - 1] == 16 and on[lost_at] == 13 and on[-1] == 0
    for name in UNITS:
        if name == "leg3":
            continue
        assert codes[name] == 1
        s = json.loads((tmp_path / f"{name}.json").read_text())
        fault = s["faults"][0]
        assert fault["cause"] == "unit_lost"
        assert fault["tick"] == lost_at  # stopped in the tick whose exchange leg3 missed
        assert s["final_stop"]["verified"] is True  # enables low, DACs 0 V, read back from its boards


@pytest.mark.slow
def test_the_coordinators_death_safe_stops_every_unit(tmp_path) -> None:
    # 5 s: six processes share two cores here; only the kill may make the coordinator silent that long
    units = start_units(tmp_path, "--unit-timeout", "5")
    coord = subprocess.Popen(vmehil("coordinate", "--rig", "melmalec-16", "--seed", "1", "--duration", "60",
                                    "--interface", "udp_multicast", "--start-timeout", "120"),
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        wait_for_exchange(50)
        os.kill(coord.pid, signal.SIGKILL)
        codes = wait_all(units)
    finally:
        for p in (coord, *units.values()):
            if p.poll() is None:
                p.kill()
    for name in UNITS:
        assert codes[name] == 1, units[name].stderr.read() if units[name].stderr else name
        s = json.loads((tmp_path / f"{name}.json").read_text())
        assert s["faults"][0]["cause"] == "coordinator_lost"
        assert s["final_stop"]["verified"] is True


@pytest.mark.slow
def test_unit_processes_with_the_coordinator_on_the_plant_node_equal_the_single_controller(tmp_path) -> None:
    """`vmehil coordinate --plant can`: the plant is `vmehil plant-node` (a seventh process on
    the plant bus, 239.74.163.2), the units on the unit bus (239.74.163.3): bit-identical."""
    node = subprocess.Popen(vmehil("plant-node", "--rig", "melmalec-16", "--interface", "udp_multicast",
                                   "--command-timeout", "0", "--json", str(tmp_path / "node.json")),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    assert node.stderr is not None
    assert node.stderr.readline().startswith("plant node: rig melmalec-16")  # serving: the coordinator may connect
    units = start_units(tmp_path)
    try:
        coord = subprocess.run(vmehil("coordinate", "--rig", "melmalec-16", "--seed", "7", "--duration", "0.8",
                                      "--interface", "udp_multicast", "--plant", "can", "--start-timeout", "120",
                                      "--can-timeout", "20", "--json", str(tmp_path / "coordinator.json")),
                               capture_output=True, text=True, timeout=600)
        assert coord.returncode == 0, coord.stderr
        assert "the plant node on udp_multicast 239.74.163.2" in coord.stderr
        assert set(wait_all(units).values()) == {0}
    finally:
        node.send_signal(signal.SIGTERM)
        node.wait(timeout=60)
        for p in units.values():
            if p.poll() is None:
                p.kill()
    summary = json.loads((tmp_path / "coordinator.json").read_text())
    steps = summary["plant_steps"]  # the run's 100 ticks and the power-up, then the units' ends
    assert summary["stop"] is None and steps >= 101 + 250 and summary["plant"] == "can"
    assert summary["timing"]["steps"] == steps and summary["timing"]["plant_p50_ms"] > 0.0  # the node's round trip
    assert {name: fig["ticks"] for name, fig in summary["units"].items()} == dict.fromkeys(UNITS, 100)
    ticks = {name: json.loads((tmp_path / f"{name}.json").read_text())["final_stop"]["tick"] for name in UNITS}
    assert steps == 1 + max(ticks.values())
    assert json.loads((tmp_path / "node.json").read_text())["steps"] == steps + 1  # and the last, all off
    assert_recorded_equal_single(tmp_path, 7, 100)
    assert_units_ended_by_category_1(tmp_path, 100)


@pytest.mark.slow
def test_a_killed_free_running_unit_process_is_lost_and_every_amplifier_ends_off(tmp_path) -> None:
    """Free-running (`--plant-mode free-running`), SIGKILL leg3 once the coordinator steps on
    the wall clock: the coordinator declares it lost within --stale-ticks periods (generous
    here: 255 periods, about 2 s, for a loaded machine), every other unit safe-stops (read
    back from its boards) and the plant ends with every amplifier off. No figure of speed."""
    units = start_units(tmp_path, "--unit-timeout", "10")
    coord = subprocess.Popen(vmehil("coordinate", "--rig", "melmalec-16", "--seed", "1", "--duration", "60",
                                    "--interface", "udp_multicast", "--start-timeout", "120", "--unit-timeout", "10",
                                    "--plant-mode", "free-running", "--stale-ticks", "255",
                                    "--json", str(tmp_path / "coordinator.json")),
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    codes = kill_leg3_at(2, coord, units)  # step 0 is the lockstep power-up; from 1 on the wall clock
    summary = json.loads((tmp_path / "coordinator.json").read_text())
    assert summary["plant_mode"] == "free-running"
    assert any(e["unit"] == "leg3" and e["what"].startswith("lost") for e in summary["events"]), summary["events"]
    assert summary["amps_on"][-1] == 0
    assert summary["stop"] is not None
    for name in UNITS:
        if name == "leg3":
            continue
        assert codes[name] == 1
        s = json.loads((tmp_path / f"{name}.json").read_text())
        assert s["faults"][0]["cause"]  # a stated cause: the lost unit's stop, or a stale answer first
        assert s["final_stop"]["verified"] is True  # enables low, DACs 0 V, read back from its boards
        assert s["plant_mode"] == "free-running" and s["timing"]["ticks"] >= 1
        if any(e["unit"] == name and e["what"] == "left" for e in summary["events"]):
            assert summary["units"][name]["realtime"] is True  # its figures came before it left
