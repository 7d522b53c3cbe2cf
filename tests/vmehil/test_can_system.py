"""End to end: the full rig (crate, drivers, servo loop) with its plant behind the CAN node.

The lockstep run over CAN must equal the in-process run bit for bit; link faults must end in the
servo loop's safe stop at the stated tick.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

import servo.runner as runner_mod
import vmehil.rig_setup.session as session
import vmehil.rig_setup.system as system_mod
from emulators.can.bus import Endpoint, open_bus, private_multicast_namespace
from emulators.can.can_plant_link import CONTROLLER_IDS, CanPlantLink
from emulators.can.codec import CanCodec
from emulators.can.dbc import ID_HEARTBEAT_PLANT, ID_SENS
from emulators.can.node import PLANT_IDS, PlantNode
from emulators.presets import resolve_rig
from servo.rig import load_rig
from tests.support.fakes import LossyEndpoint, sync_frames_of

RIG = "jpl-arm"
TICKS = 150
_chan = iter(range(1000))


def _spec():
    return load_rig(resolve_rig(RIG))


def run(spec, link=None, n=TICKS):
    from servo.motion import default_demo_motion

    system = system_mod.build_emulated_rig(spec, seed=3, link=link)
    loop = session.build_loop(system, motion=default_demo_motion(spec.n_joints), n_ticks=n)
    loop.start()
    runner_mod.LockstepRunner(system, loop).run(n)
    return system, loop


def can_link(spec, drop=(), **kw):
    from emulators.plant import Plant

    chan = f"system-{next(_chan)}"
    node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS),
                     lambda s: Plant.from_config(spec.table, seed=s), spec.n_joints)
    thread, stop = node.start_thread()
    link = CanPlantLink(LossyEndpoint(open_bus("virtual", chan), CONTROLLER_IDS, drop=sync_frames_of(drop)),
                        [j.name for j in spec.joints], seed=3, **kw)
    return link, node, thread, stop


def test_the_servo_loop_over_can_equals_the_in_process_run():
    spec = _spec()
    _, ref = run(spec)
    link, node, thread, stop = can_link(spec)
    try:
        _, got = run(spec, link)
    finally:
        stop.set()
        thread.join(10)
        node.close()
        link.close()
    a, b = ref.recorder.trimmed(), got.recorder.trimmed()
    assert ref.fault is None and got.fault is None
    for key in ("theta", "omega", "torque", "current_cmd", "theta_enc", "theta_pot", "theta_true"):
        assert np.array_equal(a[key], b[key], equal_nan=True), key
    assert np.ptp(a["theta"][:, 0]) > 0  # the demo move moved
    assert link.counters.answers == TICKS + 1


def _hang(system, loop, n: int) -> list[str]:
    """The controller hangs (no ticks) while the rig's simulated time goes on. Returns the causes
    the plant boundary raised meanwhile (over CAN: the node's latch, from its status frame)."""
    from servo.boundary import PlantBoundaryError

    causes = []
    for k in range(loop.tick_count, loop.tick_count + n):
        system.advance_to(k * system.period_ns + round(system.computation_delay_s * 1e9))
        try:
            system.exchange(k)
        except PlantBoundaryError as e:  # the link goes on stepping the plant after reporting it
            causes.append(e.cause)
        system.sense(k)
    loop.tick_count += n
    return causes


def test_the_watchdog_line_reaches_the_node_a_hung_controller_trips_as_in_process():
    spec = _spec()
    ref_system, ref = run(spec, n=60)
    assert _hang(ref_system, ref, 10) == []  # in-process: no status frame; the loop would see no current
    link, node, thread, stop = can_link(spec)
    try:
        system, got = run(spec, link, n=60)
        # over CAN the node says so: the controller learns the latch and can stop with that cause
        assert _hang(system, got, 10)[:1] == ["amplifiers_latched"]
    finally:
        stop.set()
        thread.join(10)
        node.close()
        link.close()
    assert ref_system.plant.watchdog.trips == spec.n_joints  # every amplifier was on and tripped
    assert np.array_equal(node.plant.watchdog.cause, ref_system.plant.watchdog.cause)
    # the node's own plant (the link, having reported the latch, hands the loop its held answer)
    a = ref_system.truth()
    assert np.array_equal(a["current_a"], node.plant.i) and not a["current_a"].any()


@pytest.mark.slow
def test_a_missing_answer_stops_the_loop_safely_in_that_tick():
    spec = _spec()
    # link tick 0 is the priming exchange; runner tick k exchanges link tick k + 1
    # the dropped answer is found by the timeout: 2 s, not less, while answers come, so that a
    # loaded machine's scheduling gaps before tick 51 are never taken for a missing answer; once
    # the SYNC of tick 51 is dropped its answer cannot come, and the wait is only waited out
    link, node, thread, stop = can_link(spec, drop={51}, answer_timeout_s=2.0)
    link.ep.drop = _shorten_the_wait_when(link, link.ep.drop)
    try:
        _, loop = run(spec, link, n=80)
    finally:
        stop.set()
        thread.join(10)
        node.close()
        link.close()
    assert loop.fault is not None and loop.fault.cause == "stale_sensor"
    assert loop.fault.tick == 51  # the tick after runner tick 50, whose answer never came
    assert not loop.enabled


def _shorten_the_wait_when(link, drop):
    """``drop`` that also shortens the link's answer timeout (a public attribute) once a frame is
    dropped: that tick's answer never comes, so the wait for it is waited out, not raced."""
    def dropping(m) -> bool:
        if not drop(m):
            return False
        link.answer_timeout_s = 0.25
        return True
    return dropping


@pytest.mark.slow
def test_a_vanished_node_stops_the_loop_safely():
    spec = _spec()
    # bounds far above any scheduling gap of a loaded machine: only the stopped node can trip them
    link, node, thread, stop = can_link(spec, answer_timeout_s=3.0, heartbeat_timeout_s=2.0)
    try:
        from servo.motion import default_demo_motion

        system = system_mod.build_emulated_rig(spec, seed=3, link=link)
        loop = session.build_loop(system, motion=default_demo_motion(spec.n_joints), n_ticks=60)
        loop.start()
        r = runner_mod.LockstepRunner(system, loop)
        r.run(20)
        stop.set()
        thread.join(10)
        # the node is gone: the answer wait outlasts the silence limit by 1 s, as with the bounds
        # above (3 s / 2 s), for frames it sent before it stopped that are read at the wait's start
        link.answer_timeout_s, link.heartbeat_timeout_s = 1.2, 0.2
        t0 = time.monotonic()
        r.run(40)
        assert time.monotonic() - t0 < 30  # after the failure the link no longer waits per tick
    finally:
        node.close()
        link.close()
    assert loop.fault is not None and loop.fault.cause == "plant_lost"
    assert loop.fault.tick == 21


@pytest.mark.slow
@pytest.mark.skipif(not private_multicast_namespace(), reason="udp_multicast only inside a private namespace")
def test_vmehil_run_against_a_plant_node_process_equals_the_in_process_run(tmp_path):
    _spec()
    # an equality check, not a timeout test: the wall-clock bounds (the node's amplifier command
    # timeout, the link's answer timeout) are off or generous so a loaded machine cannot trip them
    node = subprocess.Popen([sys.executable, "-m", "vmehil", "plant-node", "--rig", RIG, "--interface",
                             "udp_multicast", "--duration", "300", "--command-timeout", "0"],
                            stderr=subprocess.PIPE, text=True)
    in_process = None
    try:
        assert "plant node" in node.stderr.readline()
        common = ["--rig", RIG, "--seed", "3", "--duration", "1.0", "--quiet"]
        # the in-process run shares nothing with the node or the CAN run: it runs beside it
        in_process = subprocess.Popen([sys.executable, "-m", "vmehil", "run", *common, "--json",
                                       str(tmp_path / "a.json")], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        subprocess.run([sys.executable, "-m", "vmehil", "run", *common, "--json", str(tmp_path / "b.json"),
                        "--plant", "can", "--interface", "udp_multicast", "--can-timeout", "60",
                        "--can-log", str(tmp_path / "bus.log")],
                       check=False, capture_output=True)
        in_process.wait(120)
    finally:
        node.terminate()
        node.wait(10)
        if in_process is not None and in_process.poll() is None:
            in_process.kill()
            in_process.wait()
    a = json.loads((tmp_path / "a.json").read_text())
    b = json.loads((tmp_path / "b.json").read_text())
    assert a == b
    assert (tmp_path / "bus.log").stat().st_size > 0


def _next_frame(bus, codec: CanCodec, ids, deadline: float, what: str):
    """The next decodable frame among ``ids`` (others are skipped undecoded: the listener must keep
    up with a lockstep run's traffic); fails at ``deadline`` — a bound against hangs only."""
    while True:
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        m = bus.recv(0.5)
        if m is None or m.arbitration_id not in ids:
            continue
        f = codec.try_decode(m)
        if f is not None:
            return f


@pytest.mark.slow  # over 5 s: make test runs it, make test-fast leaves it out
@pytest.mark.skipif(not private_multicast_namespace(), reason="udp_multicast only inside a private namespace")
def test_a_sigkilled_controller_leaves_the_node_with_every_amplifier_latched_off(tmp_path):
    """SIGKILL runs no safe stop. In lockstep the plant's simulated time stops with the controller,
    so the node's wall-clock command timeout is the amplifier-side watchdog that acts."""
    spec = _spec()
    n = spec.n_joints
    # 2 s, not the default 0.2 s: a loaded machine can pause the live controller for a few hundred
    # ms, and only the kill may trip the watchdog here
    timeout_s = 2.0
    codec = CanCodec()
    watched = {ID_HEARTBEAT_PLANT} | {ID_SENS + j for j in range(n)}
    listener = open_bus("udp_multicast")
    node = subprocess.Popen([sys.executable, "-m", "vmehil", "plant-node", "--rig", RIG, "--interface", "udp_multicast",
                             "--command-timeout", str(timeout_s), "--json", str(tmp_path / "node.json"),
                             "--duration", "300"], stderr=subprocess.PIPE, text=True)
    try:
        assert "plant node" in node.stderr.readline()
        run = subprocess.Popen([sys.executable, "-m", "vmehil", "run", "--rig", RIG, "--duration", "300", "--quiet",
                                "--plant", "can", "--interface", "udp_multicast", "--can-timeout", "60"],
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            # Wait for the condition, not for a time: the node says every amplifier is on, then a
            # joint's encoder moves.
            deadline = time.monotonic() + 120
            enabled = moving = False
            while not moving:
                assert run.poll() is None, "the controller ended by itself"
                f = _next_frame(listener, codec, watched, deadline, "the amplifiers enabled and moving")
                if f.kind == "HEARTBEAT_PLANT":
                    enabled = f.raw["AmpsEnabled"] == n
                elif enabled and f.raw["EncoderCounts"] != 0:
                    moving = True
            os.kill(run.pid, signal.SIGKILL)
        finally:
            run.kill()
            run.wait(10)
        assert run.returncode == -signal.SIGKILL
        deadline = time.monotonic() + 60
        while True:
            f = _next_frame(listener, codec, {ID_HEARTBEAT_PLANT}, deadline, "the command timeout in a heartbeat")
            if f.raw["CommandTimeout"]:
                break
        assert (f.raw["AmpsEnabled"], f.raw["WatchdogTripped"], f.raw["OffCause"]) == (0, n, 2)
    finally:
        node.terminate()
        node.wait(10)
        listener.shutdown()
    summary = json.loads((tmp_path / "node.json").read_text())
    amps = summary["amplifiers"]
    assert amps["enabled"] == 0 and amps["command_timeout"] is True
    assert [j["latched_off_by"] for j in amps["per_joint"].values()] == [["command_timeout"]] * n
    assert summary["command_timeouts"] == 1 and summary["watchdog_trips"] == n
    # the node latched the amplifiers once the stated timeout had passed since the controller's
    # last SYNC, not before (the upper bound only catches a node that hung instead)
    assert timeout_s < summary["last_command_silence_s"] < timeout_s + 10.0


class _DrivenFreeRunningNode:
    """A free-running plant node stepped by the test instead of the wall clock: deterministic.

    The link's endpoint delivers each frame it sends to the node at once; when the link waits
    for an answer (a receive with a timeout and nothing queued) one node period passes. The test
    steps the node once before each servo tick, so each exchange finds the answer of the
    period that just ended (computed with the previous tick's command, as free-running does).
    """

    def __init__(self, spec, chan: str) -> None:
        from emulators.can.node import node_spec
        from emulators.plant import Plant

        ns = node_spec(RIG)
        self.period_s, self.delay_s = ns.period_s, ns.delay_s
        self.t = 0.0
        self.node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS),
                              lambda s: Plant.from_config(spec.table, seed=s), spec.n_joints, seed=3,
                              free_running=True, period_s=ns.period_s, delay_s=ns.delay_s, clock=lambda: self.t)
        self.free_tick = 0
        node = self

        class Ep(Endpoint):
            def send(self, msg) -> None:
                super().send(msg)
                node.deliver()

            def recv(self, timeout):
                m = super().recv(0.0)
                if m is None and timeout:
                    node.step()
                    m = super().recv(0.0)
                return m

        self.link_endpoint = Ep(open_bus("virtual", chan), CONTROLLER_IDS)

    def deliver(self) -> None:
        while (m := self.node.ep.recv(0.0)) is not None:
            self.node.handle(m)

    def step(self) -> None:
        self.t += self.period_s
        self.deliver()
        self.node.heartbeat()
        self.node.step(self.free_tick, self.period_s, self.delay_s)
        self.free_tick += 1

    def close(self) -> None:
        self.node.close()


def test_free_running_the_loop_starts_on_the_reset_plant_not_on_answers_queued_before_it():
    """The node free-runs its previous plant until our RESET; answers of it were still queued when
    the link read its first one, and the watchdog stopped the run in its first ticks (4 runs of 4)."""
    from servo.motion import default_demo_motion

    spec = _spec()
    driven = _DrivenFreeRunningNode(spec, f"system-{next(_chan)}")
    for _ in range(120):  # ~1 s of the old plant (gravity moves it), its answers queued for the link
        driven.step()
    link = CanPlantLink(driven.link_endpoint, [j.name for j in spec.joints], seed=3, free_running=True)
    try:
        system = system_mod.build_emulated_rig(spec, seed=3, link=link)
        loop = session.build_loop(system, motion=default_demo_motion(spec.n_joints), n_ticks=TICKS)
        loop.start()
        # free-running answers lag the commands: the current cross-check allows for it
        assert loop.watchdog.command_lag_ticks == system.answer_lag_ticks == 2
        runner = runner_mod.LockstepRunner(system, loop)
        for _ in range(TICKS):
            driven.step()
            runner.tick()
    finally:
        link.close()
        driven.close()
    assert loop.fault is None, loop.fault
    assert link.counters.other_session >= 120 and link.counters.stale == 0
    theta = loop.recorder.trimmed()["theta"]
    assert np.ptp(theta[:, 1]) > 0.01  # the demo move moved
    assert np.abs(np.diff(theta, axis=0)).max() < 0.02  # continuous: no jump to or from an old state


@pytest.mark.parametrize("totals", [True, False], ids=["totals", "no-totals"])
def test_free_running_answers_lost_on_the_way_lose_no_encoder_count(monkeypatch, totals):
    """A free-running node steps 0-2 times per servo tick and a fifth of its answers never reach
    the link (a receiver's full socket buffer, a lost frame): the encoder's counts of the lost
    answers come back through SENS.EncoderTotal, so the encoder agrees with the pot and the run
    goes on. Without the totals (the frames' own counts only) the same run stops on the
    encoder/pot cross-check: the counts of the lost answers are gone for good."""
    from emulators.can.codec import EncoderTotals
    from servo.motion import default_demo_motion

    if not totals:  # the node keeps no totals: every SENS frame says HasTotal = 0
        monkeypatch.setattr(EncoderTotals, "add", lambda self, encoder: None)
    spec = _spec()
    driven = _DrivenFreeRunningNode(spec, f"system-{next(_chan)}")
    rng = np.random.default_rng(7)
    lost = 0

    def step_maybe_lost() -> None:
        nonlocal lost
        if driven.free_tick > 2 and rng.random() < 0.2:  # this step's answer never arrives
            send = driven.node._send
            driven.node._send = lambda msg: None
            try:
                driven.step()
            finally:
                driven.node._send = send
            lost += 1
        else:
            driven.step()

    link = CanPlantLink(driven.link_endpoint, [j.name for j in spec.joints], seed=3, free_running=True,
                        stale_ticks=50)
    try:
        system = system_mod.build_emulated_rig(spec, seed=3, link=link)
        loop = session.build_loop(system, motion=default_demo_motion(spec.n_joints), n_ticks=TICKS)
        loop.start()
        runner = runner_mod.LockstepRunner(system, loop)
        for _ in range(TICKS):
            for _ in range(int(rng.choice([0, 1, 1, 2]))):  # the node's steps in this servo period
                step_maybe_lost()
            runner.tick()
            if loop.fault is not None:
                break
    finally:
        link.close()
        driven.close()
    assert lost > 10
    if totals:
        assert loop.fault is None, loop.fault
        assert link.totals.recovered > 0
        theta = loop.recorder.trimmed()["theta"]
        assert np.ptp(theta[:, 1]) > 0.01  # the demo move moved
    else:
        assert loop.fault is not None and loop.fault.cause == "position_mismatch", loop.fault
