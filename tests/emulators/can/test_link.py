"""The plant as a CAN node: the same test bodies over every transport.

Transports: ``inprocess`` (the plant object in this process, through the same quantization),
``virtual`` (python-can's in-process bus, node in a thread, separate objects), ``socketcan``
(vcan0, skipped where AF_CAN or vcan0 is missing) and ``udp_multicast`` (the node in a second
process; skipped unless inside a private loopback-only network namespace — ``make test`` creates
one). The plant is :class:`emulators.can.toy.ToyPlant` so the transport is tested on its own; the
end-to-end run through the full servo stack is in ``test_can_system.py``.
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from contextlib import contextmanager

import can
import numpy as np
import pytest

from emulators.can.bus import (
    Endpoint,
    open_bus,
    private_multicast_namespace,
    socketcan_available,
    vcan_exists,
)
from emulators.can.can_plant_link import CONTROLLER_IDS, CanPlantLink
from emulators.can.codec import DbcExchangeCodec
from emulators.can.node import PLANT_IDS, PlantNode
from emulators.can.toy import ToyCommand, ToyPlant, ToySensors
from emulators.harness import InProcessLink, PlantLostError, PlantRestartedError, StaleDataError
from tests.support.fakes import LossyEndpoint

TRANSPORTS = ["inprocess", "virtual", "socketcan", "udp_multicast"]
CAN_TRANSPORTS = TRANSPORTS[1:]
N = 3
PERIOD, DELAY = 0.008, 0.001
_port = iter(range(43200, 43999))


def skip_unless_available(transport: str) -> None:
    if transport == "socketcan" and not (socketcan_available() and vcan_exists("vcan0")):
        pytest.skip("socketcan: no AF_CAN sockets or no vcan0 here (sudo ./vcan_setup.sh)")
    if transport == "udp_multicast" and not private_multicast_namespace():
        pytest.skip("udp_multicast: only inside a private loopback-only network namespace (make test)")


def command(k: int, n: int = N) -> ToyCommand:
    """A deterministic command sequence exercising every signal."""
    v = np.array([0.4 * np.sin(k / 9.0 + i) for i in range(n)])
    return ToyCommand(amp_command_v=v, amp_enable=np.ones(n, bool), fault_reset=np.array([k % 50 == 0] * n),
                      pwm_duty=np.full(n, (k % 7) / 7.0), pwm_direction=np.array([k % 3 != 0] * n),
                      brake=np.zeros(n, bool))


class Pair:
    """A controller-side link and, for CAN, the node serving it (thread or process)."""

    def __init__(self, transport: str, *, seed: int = 7, free_running: bool = False, drop=None,
                 log_path=None, **link_kw) -> None:
        self.transport = transport
        self.seed = seed
        self.free_running = free_running
        self.node: PlantNode | None = None
        self.thread = self.stop = self.proc = None
        if transport == "inprocess":
            self.link = InProcessLink(ToyPlant(N, seed=seed), DbcExchangeCodec())
            return
        self.channel, self.kw = self._bus_args()
        self.start_node()
        bus = open_bus(transport, self.channel, **self.kw)
        ep = LossyEndpoint(bus, CONTROLLER_IDS, drop=drop, log_path=log_path)
        link_kw.setdefault("connect_timeout_s", 20.0)
        # tests that do not test a timeout get bounds no loaded machine's pause reaches
        link_kw.setdefault("answer_timeout_s", 10.0)
        link_kw.setdefault("heartbeat_timeout_s", 10.0)
        self.link = CanPlantLink(ep, [f"j{i}" for i in range(N)], seed=seed, free_running=free_running,
                                 sensors_type=ToySensors, **link_kw)

    def _bus_args(self):
        if self.transport == "virtual":
            return f"vmehil-test-{next(_port)}", {}
        if self.transport == "socketcan":
            return "vcan0", {}
        return "239.74.163.2", {"port": next(_port)}

    def start_node(self) -> None:
        if self.transport == "udp_multicast":
            cmd = [sys.executable, "-m", "emulators.can.toy", "--interface", "udp_multicast", "--channel",
                   self.channel, "--port", str(self.kw["port"]), "--joints", str(N), "--seed", "0"]
            if self.free_running:
                cmd.append("--free-running")
            self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            assert "ready" in self.proc.stdout.readline()
            return
        bus = open_bus(self.transport, self.channel, **self.kw)
        self.node = PlantNode(Endpoint(bus, PLANT_IDS), lambda s: ToyPlant(N, seed=s), N,
                              free_running=self.free_running, command_type=ToyCommand, period_s=PERIOD,
                              delay_s=DELAY)
        self.thread, self.stop = self.node.start_thread()

    def stop_node(self) -> None:
        if self.proc is not None:
            self.proc.terminate()
            self.proc.wait(10)
            self.proc = None
        if self.thread is not None:
            self.stop.set()
            self.thread.join(10)
            self.node.close()
            self.thread = None

    def close(self) -> None:
        self.stop_node()
        self.link.close()


@contextmanager
def pair(transport: str, **kw):
    skip_unless_available(transport)
    p = Pair(transport, **kw)
    try:
        yield p
    finally:
        p.close()


def run_ticks(link, n_ticks: int, start: int = 0) -> list[ToySensors]:
    return [link.exchange(command(k), PERIOD, DELAY) for k in range(start, start + n_ticks)]


def reference(n_ticks: int, seed: int = 7) -> list[ToySensors]:
    return run_ticks(InProcessLink(ToyPlant(N, seed=seed), DbcExchangeCodec()), n_ticks)


def assert_same(a: list[ToySensors], b: list[ToySensors]) -> None:
    assert len(a) == len(b)
    for k, (x, y) in enumerate(zip(a, b, strict=True)):
        for f in ("pot_v", "tach_v", "imon_v", "amp_fault", "switching"):
            assert np.array_equal(getattr(x, f), getattr(y, f)), (k, f)
        assert x.encoder == y.encoder, k
        for key in ("theta_joint", "omega_joint", "current_a"):
            assert np.array_equal(x.truth[key], y.truth[key]), (k, key)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_lockstep_equals_the_in_process_run_bit_for_bit(transport):
    ref = reference(200)
    with pair(transport) as p:
        got = run_ticks(p.link, 200)
        assert_same(got, ref)
        if transport != "inprocess":
            assert p.link.counters.answers == 200 and p.link.counters.stale == 0
    # the toy really moves and crosses encoder indexes, so the comparison is not vacuous
    assert abs(sum(s.encoder[0].counts for s in ref)) > 1000
    assert any(s.encoder[0].index_offsets for s in ref)


@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_a_second_controller_run_resets_the_node_and_matches_again(transport):
    ref = reference(60)
    with pair(transport) as p:
        assert_same(run_ticks(p.link, 60), ref)
        p.link.close()
        bus = open_bus(transport, p.channel, **p.kw)
        p.link = CanPlantLink(Endpoint(bus, CONTROLLER_IDS), [f"j{i}" for i in range(N)], seed=7,
                              sensors_type=ToySensors, connect_timeout_s=20.0)
        assert_same(run_ticks(p.link, 60), ref)


# The timeouts below are how a missing answer or a silent node is found. The ticks that are
# answered run under Pair's 10 s bounds, far above any scheduling gap of a loaded 2-core machine;
# only once the frame is dropped or the node stopped for good (no answer can come any more) are
# the link's timeouts shortened (its public attributes) to what the test then waits out.
WAITED_OUT_S = 0.25  # an answer that can no longer come: the wait is waited out, not raced
@pytest.mark.slow
@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_a_missing_answer_is_stale_data_at_that_tick(transport):
    # drop the SYNC of tick 40: the node never answers it
    drop = drop_sync_at({40})
    with pair(transport, drop=drop) as p:
        run_ticks(p.link, 40)
        p.link.answer_timeout_s = WAITED_OUT_S  # the SYNC of tick 40 is dropped: its answer never comes
        with pytest.raises(StaleDataError) as e:
            p.link.exchange(command(40), PERIOD, DELAY)
        assert "tick 40" in str(e.value) and not isinstance(e.value, PlantLostError)
        assert e.value.cause == "stale_sensor"
        # afterwards the link no longer waits and returns held values without encoder motion
        s = p.link.exchange(command(41), PERIOD, DELAY)
        assert all(ev.counts == 0 for ev in s.encoder)


@pytest.mark.slow
@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_stale_ticks_allows_held_values_before_the_safe_stop(transport):
    drop = drop_sync_at({20, 21, 22})
    with pair(transport, drop=drop, stale_ticks=3) as p:
        got = run_ticks(p.link, 20)
        p.link.answer_timeout_s = WAITED_OUT_S  # the SYNCs of ticks 20-22 are dropped: no answer comes
        held = run_ticks(p.link, 2, start=20)
        for s in held:
            assert np.array_equal(s.pot_v, got[-1].pot_v) and all(ev.counts == 0 for ev in s.encoder)
        with pytest.raises(StaleDataError):
            p.link.exchange(command(22), PERIOD, DELAY)
        assert p.link.counters.stale == 3


def drop_sync_at(ticks: set[int]):
    from emulators.can.dbc import ID_SYNC

    def drop(m: can.Message) -> bool:
        return m.arbitration_id == ID_SYNC and int.from_bytes(m.data[:4], "little") in ticks
    return drop


@pytest.mark.slow
@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_a_vanished_node_is_reported_as_lost(transport):
    with pair(transport) as p:
        run_ticks(p.link, 10)
        p.stop_node()
        # the node is gone: the answer wait outlasts the silence limit by 1 s, as before (3 s / 2 s),
        # for the frames it sent before it stopped that are read at the start of the wait
        p.link.answer_timeout_s, p.link.heartbeat_timeout_s = 1.2, 0.2
        with pytest.raises(PlantLostError) as e:
            p.link.exchange(command(10), PERIOD, DELAY)
        assert e.value.cause == "plant_lost"


@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_a_restarted_node_is_detected(transport):
    with pair(transport, answer_timeout_s=5.0) as p:
        run_ticks(p.link, 10)
        p.stop_node()
        p.start_node()  # a new boot id; it steps our next SYNC without a RESET
        with pytest.raises(PlantRestartedError) as e:
            for k in range(10, 100):
                p.link.exchange(command(k), PERIOD, DELAY)
        assert e.value.cause == "plant_restarted"


@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_garbage_on_the_bus_is_counted_and_dropped_without_changing_results(transport):
    ref = reference(80)
    with pair(transport) as p:
        noise_bus = open_bus(transport, p.channel, **p.kw)
        rng = np.random.default_rng(3)
        stop = threading.Event()

        # CMD_J00 with PwmDuty raw 2^20 - 1 (> 1.0): the right length, out of range
        out_of_range = bytes([0, 0, 0, 0xFF, 0xFF, 0x0F, 0, 0, 0, 0, 0, 0])  # CMD: 12 bytes (FD) since #29

        ids = [0x7FF, 0x080, 0x100, 0x200, 0x280, 0x281, 0x123]
        # one frame of every bad kind goes out before the first tick, so both sides' counters
        # have something to count however the spam thread is scheduled on a loaded machine
        first_round = [can.Message(arbitration_id=0x100, data=out_of_range, is_extended_id=False, is_fd=True)]
        first_round += [can.Message(arbitration_id=fid, data=bytes(size), is_extended_id=False, is_fd=size > 8)
                        for fid in ids for size in (0, 3, 20)]
        sent_first_round = threading.Event()

        def spam() -> None:
            for m in first_round:
                noise_bus.send(m)
            sent_first_round.set()
            k = 0
            while not stop.is_set():
                k += 1
                if k % 4 == 0:
                    noise_bus.send(can.Message(arbitration_id=0x100, data=out_of_range, is_extended_id=False,
                                               is_fd=True))
                else:  # unknown identifiers and wrong lengths for every known one
                    fid = int(rng.choice(ids))
                    size = int(rng.choice([0, 3, 20, 64]))  # 20: no frame's length (CMD is 12 since #29)
                    data = bytes(rng.integers(0, 256, size, dtype=np.uint8))
                    noise_bus.send(can.Message(arbitration_id=fid, data=data, is_extended_id=False, is_fd=size > 8))
                time.sleep(0.001)

        t = threading.Thread(target=spam, daemon=True)
        t.start()
        try:
            assert sent_first_round.wait(30)
            got = run_ticks(p.link, 80)
        finally:
            stop.set()
            t.join(5)
            noise_bus.shutdown()
        # every bad frame was dropped by both sides; the run is identical
        c = p.link.codec.counters
        assert c.unknown_id > 0 and c.wrong_length > 0
        if p.node is not None:
            k = p.node.codec.counters
            assert k.out_of_range > 0 and k.wrong_length > 0
        assert_same(got, ref)


@pytest.mark.parametrize("transport", ["virtual", "socketcan"])
def test_sequence_jumps_and_missing_commands_are_counted_by_the_node(transport):
    with pair(transport) as p:
        run_ticks(p.link, 5)
        raw = open_bus(transport, p.channel, **p.kw)
        try:
            # a SYNC for tick 1000 with no commands: a jump, and N missing command frames
            raw.send(p.link.codec.frame("SYNC", Tick=1000, PeriodS=PERIOD, DelayS=DELAY, Seq=1000 & 0xFF,
                                        BootId=p.link.boot_id))
            deadline = time.monotonic() + 10
            while p.node.counters.seq_jumps == 0 and time.monotonic() < deadline:
                time.sleep(0.01)
        finally:
            raw.shutdown()
        assert p.node.counters.seq_jumps == 1
        assert p.node.counters.missing_cmd == N


@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_free_running_latches_newest_values_and_keeps_every_encoder_count(transport):
    with pair(transport, free_running=True, stale_ticks=1000, heartbeat_timeout_s=5.0) as p:
        link = p.link
        total = np.zeros(N, int)
        last = None
        first_x4 = None
        for k in range(60):
            s = link.exchange(command(k), PERIOD, DELAY)
            if first_x4 is None:
                first_x4 = np.floor(s.truth["theta_joint"] * ToyPlant.RATIO / (2 * np.pi) * 4 * ToyPlant.LINES)
            else:
                total += [ev.counts for ev in s.encoder]
            last = s
            time.sleep(PERIOD)
        assert link.counters.answers > 1
        x4 = np.floor(last.truth["theta_joint"] * ToyPlant.RATIO / (2 * np.pi) * 4 * ToyPlant.LINES)
        # counts accumulated over every answer (several per exchange or none) add up to the motion
        assert np.all(np.abs(total - (x4 - first_x4)) <= 1)
        assert np.any(np.abs(total) > 10)


@pytest.mark.parametrize("transport", CAN_TRANSPORTS)
def test_free_running_node_going_silent_is_a_safe_stop(transport):
    with pair(transport, free_running=True, stale_ticks=25, heartbeat_timeout_s=2.0) as p:
        for k in range(5):
            p.link.exchange(command(k), PERIOD, DELAY)
            time.sleep(PERIOD)
        p.stop_node()
        with pytest.raises(StaleDataError):  # stale (25 ticks) or lost (heartbeat), whichever first
            for k in range(5, 500):
                p.link.exchange(command(k), PERIOD, DELAY)
                time.sleep(PERIOD)


def test_a_mode_mismatch_is_refused_with_advice():
    from emulators.harness import PlantLinkError

    with pair("virtual") as p:
        p.link.close()
        bus = open_bus("virtual", p.channel)
        link = CanPlantLink(Endpoint(bus, CONTROLLER_IDS), [f"j{i}" for i in range(N)], free_running=True,
                            sensors_type=ToySensors)
        with pytest.raises(PlantLinkError,
                           match="give this side --plant-mode lockstep, or restart the node with --free-running"):
            link.connect()
        link.close()


def _wait_for(condition, what: str, limit_s: float = 30.0) -> None:
    """Wait for ``condition()`` (a generous limit only against a hang: no timing is asserted)."""
    deadline = time.monotonic() + limit_s
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"gave up waiting for {what}")
        time.sleep(0.001)


def test_free_running_the_first_answers_after_connect_are_the_new_sessions_not_queued_old_ones():
    """Free-running, the node steps its previous plant until our RESET; those answers were still
    queued when the link read its first one (the servo loop saw the joints jump 0.1–0.9 rad).
    Every answer the link returns must come from the plant rebuilt by our RESET, in order."""
    from emulators.can.node import node_spec
    from emulators.plant import Plant, PlantCommand

    spec = node_spec("jpl-arm")
    chan = f"vmehil-test-{next(_port)}"
    node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS), lambda s: Plant.from_config(spec.table, seed=s),
                     spec.n_joints, seed=3, free_running=True, period_s=spec.period_s, delay_s=spec.delay_s)
    ep = Endpoint(open_bus("virtual", chan), CONTROLLER_IDS)  # frames queue here from now on
    thread, stop = node.start_thread()
    link = CanPlantLink(ep, spec.names, seed=3, free_running=True, stale_ticks=10_000, heartbeat_timeout_s=30.0)
    cmd = PlantCommand.idle(spec.n_joints)
    cmd.holding_brake[:] = True  # the holding brakes released: gravity moves the joints
    try:
        _wait_for(lambda: node.counters.steps >= 100, "100 steps of the node's first plant")  # gravity moves it
        link.connect()
        thetas = []
        for _ in range(30):
            seen = node.counters.steps
            _wait_for(lambda seen=seen: node.counters.steps > seen, "a node step")
            thetas.append(link.exchange(cmd, spec.period_s, spec.delay_s).truth["theta_joint"].copy())
    finally:
        stop.set()
        thread.join(10)
        node.close()
        link.close()
    assert link.counters.other_session > 0  # old answers were queued, and discarded
    # the plant our RESET built, stepped as the node steps it (our idle commands), row k = step k + 1
    ref_plant = Plant.from_config(spec.table, seed=3)
    ref_cmd = node.codec.command_from_raw({**node.codec.command_raw(cmd), "Watchdog": np.asarray(0)}, PlantCommand)
    ref = np.array([ref_plant.step_period(ref_cmd, spec.period_s, spec.delay_s).truth["theta_joint"].copy()
                    for _ in range(node.counters.steps)])
    assert np.ptp(ref[:, 1]) > 0.01  # the joints really move (gravity): the states are distinct
    steps = []
    for theta in thetas:
        err = np.abs(ref - theta).max(axis=1)
        assert err.min() == 0.0, "an answer that is no step of the plant our RESET built"
        steps.append(int(err.argmin()))
    assert steps == sorted(steps)  # continuous: never back to an older state


@contextmanager
def node_and_links(n_links: int, *, controller_timeout_s: float, **link_kw):
    """A lockstep toy node (thread) on ``virtual`` and ``n_links`` links (not yet connected)."""
    chan = f"vmehil-test-{next(_port)}"
    node = PlantNode(Endpoint(open_bus("virtual", chan), PLANT_IDS), lambda s: ToyPlant(N, seed=s), N,
                     command_type=ToyCommand, period_s=PERIOD, delay_s=DELAY,
                     controller_timeout_s=controller_timeout_s)
    links = [CanPlantLink(Endpoint(open_bus("virtual", chan), CONTROLLER_IDS), [f"j{i}" for i in range(N)], seed=7,
                          sensors_type=ToySensors, **link_kw) for _ in range(n_links)]
    thread, stop = node.start_thread()
    try:
        yield node, links
    finally:
        stop.set()
        thread.join(10)
        node.close()
        for link in links:
            link.close()


def test_a_second_controller_is_refused_while_the_first_runs_and_told_why():
    from emulators.harness import PlantLinkError

    ref = reference(40)
    with node_and_links(2, controller_timeout_s=60.0, connect_timeout_s=0.5) as (node, (first, second)):
        got = run_ticks(first, 20)
        with pytest.raises(PlantLinkError, match=r"serves another controller \(boot id"):
            second.connect()
        got += run_ticks(first, 20, start=20)  # undisturbed
        assert_same(got, ref)
        assert node.counters.refused_resets >= 1 and node.refused_boot == second.boot_id
        assert first.counters.peer_refused >= 1  # reported in PLANT_SESSION


def test_a_closed_link_ends_its_session_and_the_next_controller_connects_at_once():
    ref = reference(30)
    # a controller timeout far beyond the connect timeout: only END can free the node in time
    with node_and_links(2, controller_timeout_s=60.0, connect_timeout_s=5.0) as (node, (first, second)):
        assert_same(run_ticks(first, 30), ref)
        first.close()
        assert_same(run_ticks(second, 30), ref)
        assert node.session_owner == second.boot_id


def test_a_link_whose_session_was_taken_over_stops():
    from emulators.can.can_plant_link import SessionLostError

    with node_and_links(2, controller_timeout_s=0.05, answer_timeout_s=2.0) as (node, (first, second)):
        run_ticks(first, 10)
        _wait_for(node.session_open, "the first controller's session to time out")
        second.connect()
        with pytest.raises(SessionLostError) as e:
            first.exchange(command(10), PERIOD, DELAY)
        assert e.value.cause == "plant_restarted"
        steps = node.counters.steps
        run_ticks(second, 5)
        assert node.counters.steps == steps + 5
