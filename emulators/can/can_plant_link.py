"""The controller side of the plant node: :class:`CanPlantLink`, a :class:`~emulators.plant_link.PlantLink`
that exchanges frames of ``vmehil.dbc`` with a :class:`~emulators.can.node.PlantNode`.

**Lockstep** (default): each :meth:`CanPlantLink.exchange` sends ``CMD_Jxx`` (``Seq`` = tick mod
256) and ``SYNC`` (tick, period, delay), then waits up to ``answer_timeout_s`` for the complete
answer of that tick (every ``SENS_Jxx`` with the tick's ``Seq``, then ``PLANT_STATUS`` with the
tick). Values pass through the same quantization as :class:`~emulators.can.codec.DbcExchangeCodec`,
so results are bit-identical to the in-process run with the same seed.

**Free-running**: the plant steps on its own clock; each exchange sends the commands, takes
every complete answer that arrived since the last exchange without waiting, latches the newest
analog values and accumulates the encoder events of all of them.

Faults (each raises a :class:`~emulators.plant_link.PlantLinkError` subclass, which the runner turns
into a safe stop in the same tick):

* no complete answer for ``stale_ticks`` consecutive exchanges → :class:`StaleDataError`
  (lockstep default 1: the tick whose answer is missing; free-running default 5). Exchanges
  before that return the held values with no encoder motion.
* nothing at all from the plant node (no answer, no heartbeat) for ``heartbeat_timeout_s`` →
  :class:`PlantLostError`.
* the node restarted: ``RESTART_EVIDENCE_FRAMES`` (3) status or heartbeat frames in a row from
  one boot id other than the one that acknowledged our RESET, with nothing from that one between
  them → :class:`PlantRestartedError`. A single frame of another boot id proves nothing (a stray
  or corrupted frame, another session's node): it is dropped and counted
  (``LinkCounters.other_boot``), as is a SENS frame whose ``BootIdLow`` is not our node's.
* the node acknowledging another controller's RESET, or reporting another owner
  (``PLANT_SESSION``), after it acknowledged ours → :class:`SessionLostError` (a
  :class:`PlantRestartedError`: the plant is no longer ours).

**Sessions.** RESET carries this link's boot id; the node's acknowledgement names it (``Tick``)
and the session number (``Session``). Only answers of that session are used: frames the node
sent before it acknowledged our RESET (its previous session's plant, still queued — in
free-running mode the first exchange used to read them), or for another session, are
discarded and counted (``LinkCounters.other_session``). CMD and SYNC carry our boot id so the
node obeys only its session's owner; :meth:`CanPlantLink.close` sends ``END``, which frees the
node for the next controller at once.

After a failure the link keeps sending commands (so a live node sees the safe outputs) but
no longer waits: it returns the held values at once.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import can
import numpy as np

from emulators.can.bus import Endpoint
from emulators.can.codec import CanCodec, EncoderTotals, Frame
from emulators.can.dbc import (
    CONTROL_END,
    CONTROL_RESET,
    ID_CMD,
    ID_CONTROL,
    ID_HEARTBEAT_CONTROLLER,
    ID_SYNC,
    MAX_JOINTS,
    OFF_CAUSES,
)
from emulators.can.node import new_boot_id
from emulators.plant_link import (
    AmplifiersLatchedError,
    PlantLink,
    PlantLinkError,
    PlantLostError,
    PlantRestartedError,
    StaleDataError,
)
from emulators.signals import QuadratureEvents

CONTROLLER_IDS = {ID_SYNC, ID_CONTROL, ID_HEARTBEAT_CONTROLLER} | {ID_CMD + j for j in range(MAX_JOINTS)}

__all__ = ["CanPlantLink", "LinkCounters", "PlantLinkError", "PlantLostError", "PlantRestartedError",
           "SessionLostError", "StaleDataError"]


class SessionLostError(PlantRestartedError):
    """The plant node now serves another controller's session: its plant is no longer ours."""


@dataclass
class LinkCounters:
    answers: int = 0
    stale: int = 0
    late: int = 0
    incomplete: int = 0
    foreign: int = 0
    peer_missing_cmd: int = 0
    peer_dropped: int = 0
    peer_seq_jumps: int = 0
    #: the node's last status said an amplifier is latched off by its enable watchdog / command timeout
    peer_watchdog_tripped: bool = False
    #: answers discarded: sent before the node acknowledged our RESET, or for another session
    other_session: int = 0
    #: the node's count of frames it refused from controllers other than its session's owner
    peer_refused: int = 0
    #: status and heartbeat frames with a boot id other than our node's: dropped (see the module doc)
    other_boot: int = 0


#: status/heartbeat frames in a row from one new boot id, none from our node's between them, that
#: prove the node restarted: a restarted node sends a heartbeat every 0.1 s and answers each SYNC,
#: so it shows within a tick or two; a random frame carries a random boot id and never repeats one
RESTART_EVIDENCE_FRAMES = 3


def merge_events(events: list[QuadratureEvents]) -> QuadratureEvents:
    """Several consecutive intervals' encoder events as one interval."""
    counts = illegal = 0
    offsets: list[int] = []
    phase = 0
    for ev in events:
        offsets.extend(counts + o for o in ev.index_offsets)
        counts += ev.counts
        illegal += ev.illegal
        phase = ev.phase
    return QuadratureEvents(counts=counts, illegal=illegal, index_offsets=tuple(offsets), phase=phase)


class CanPlantLink(PlantLink):
    """A plant on the other side of a CAN bus.

    Args:
        endpoint: this side's :class:`~emulators.can.bus.Endpoint` (or a python-can bus).
        names: joint names (their number must match the node's).
        seed: plant seed sent with RESET (the node rebuilds its plant with it).
        free_running: latch the newest values instead of stepping the plant per exchange.
        answer_timeout_s: lockstep: how long to wait for a tick's answer (s, wall clock).
        connect_timeout_s: how long to wait for the node to acknowledge RESET (s).
        stale_ticks: consecutive exchanges without a fresh answer that raise StaleDataError.
        heartbeat_timeout_s: silence of the node that raises PlantLostError (s).
        heartbeat_s: interval of this side's heartbeat (s).
        sensors_type: the sensors class (default :class:`emulators.plant.PlantSensors`).
    """

    def __init__(self, endpoint: Endpoint | can.BusABC, names: list[str], *, seed: int = 0,
                 free_running: bool = False, answer_timeout_s: float = 1.0, connect_timeout_s: float = 5.0,
                 stale_ticks: int | None = None, heartbeat_timeout_s: float = 1.0, heartbeat_s: float = 0.1,
                 sensors_type: Callable[..., Any] | None = None, codec: CanCodec | None = None,
                 boot_id: int | None = None) -> None:
        self.ep = endpoint if isinstance(endpoint, Endpoint) else Endpoint(endpoint, CONTROLLER_IDS, owns_bus=False)
        self.ep.own_ids |= CONTROLLER_IDS
        self.codec = codec or CanCodec()
        self.names = list(names)
        self.n = len(self.names)
        self.codec.check_joints(self.n)
        self.seed = int(seed)
        self.free_running = free_running
        self.answer_timeout_s = answer_timeout_s
        self.connect_timeout_s = connect_timeout_s
        self.stale_ticks = stale_ticks if stale_ticks is not None else (5 if free_running else 1)
        if self.stale_ticks < 1:
            raise ValueError("stale_ticks must be >= 1")
        self.heartbeat_timeout_s = heartbeat_timeout_s
        self.heartbeat_s = heartbeat_s
        if sensors_type is None:
            from emulators.plant import PlantSensors

            sensors_type = PlantSensors
        self.sensors_type = sensors_type
        self.boot_id = new_boot_id() if boot_id is None else boot_id & 0xFFFF
        self.counters = LinkCounters()
        self.tick = 0
        self.peer_boot: int | None = None
        self.connected = False
        self.failed: PlantLinkError | None = None
        self._stale_run = 0
        self._held = None
        self._last_peer = time.monotonic()
        self._next_hb = 0.0
        self._hb_counter = 0
        self._sens: dict[int, dict[str, Any]] = {}
        self._truth: dict[int, dict[str, Any]] = {}
        self._fresh: list[tuple[int, Any]] = []  # complete answers not yet consumed: (tick, sensors)
        #: the node's running encoder totals: the counts of answers that never arrived are not lost
        self.totals = EncoderTotals()
        self._reset_acked = False
        self.session: int | None = None  #: the node's number of our session (from its acknowledgement)
        self._refused_by: int | None = None  # while connecting: the owner of the session that refused us
        self._other_boot: int | None = None  # the boot id of the last frames not of our node's, and
        self._other_run = 0  # how many of them came in a row (RESTART_EVIDENCE_FRAMES)
        self._taken_by: int | None = None  # PLANT_SESSION frames in a row naming one other owner
        self._taken_run = 0
        self._peer_off_cause = 0  # the node's last HEARTBEAT_PLANT.OffCause (why amplifiers are latched)

    # --- sending --------------------------------------------------------------------------------
    def _heartbeat(self, now: float) -> None:
        if now < self._next_hb:
            return
        self._next_hb = now + self.heartbeat_s
        self._hb_counter = (self._hb_counter + 1) & 0xFF
        self.ep.send(self.codec.frame("HEARTBEAT_CONTROLLER", State=2, BootId=self.boot_id,
                                      Counter=self._hb_counter, Tick=self.tick & 0xFFFFFFFF))

    def connect(self) -> None:
        """RESET the node's plant with our seed and wait for its acknowledgement (resending every
        0.2 s up to ``connect_timeout_s``)."""
        t_end = time.monotonic() + self.connect_timeout_s
        self._reset_acked = False
        while True:
            now = time.monotonic()
            self.ep.send(self.codec.frame("CONTROL", Command=CONTROL_RESET, Seed=self.seed & 0xFFFFFFFF,
                                          NJoints=self.n, BootId=self.boot_id))
            t_resend = min(now + 0.2, t_end)
            while time.monotonic() < t_resend:
                self._pump(t_resend - time.monotonic(), accept_new_boot=True)
                if self._reset_acked:
                    self.connected = True
                    self._last_peer = time.monotonic()
                    return
            if time.monotonic() >= t_end:
                if self._refused_by is not None:
                    raise PlantLinkError(
                        f"the plant node serves another controller (boot id {self._refused_by:#06x}) and refused "
                        f"our RESET for {self.connect_timeout_s:g} s: it accepts a new controller when that one "
                        "ends its run or has been silent for the node's controller timeout (0.5 s)")
                raise PlantLostError(f"no plant node answered RESET within {self.connect_timeout_s:g} s")

    # --- receiving ------------------------------------------------------------------------------
    def _pump(self, timeout: float, *, accept_new_boot: bool = False) -> bool:
        """Receive and process one frame (waiting up to ``timeout``); False when none came."""
        m = self.ep.recv(max(0.0, timeout))
        if m is None:
            return False
        f = self.codec.try_decode(m)
        if f is None:
            return True
        self._process(f, accept_new_boot)
        return True

    def _ours(self, boot: int, accept_new_boot: bool) -> bool:
        """Whether a status or heartbeat frame with boot id ``boot`` is our node's (to be used).
        Another boot id's is dropped and counted; :data:`RESTART_EVIDENCE_FRAMES` of one new
        boot id in a row, none of our node's between, raise :class:`PlantRestartedError`."""
        if accept_new_boot or self.peer_boot is None or boot == self.peer_boot:
            self._other_boot, self._other_run = None, 0
            return True
        self.counters.other_boot += 1
        if boot == self._other_boot:
            self._other_run += 1
        else:
            self._other_boot, self._other_run = boot, 1
        if self._other_run >= RESTART_EVIDENCE_FRAMES:
            raise PlantRestartedError(f"the plant node restarted (boot id {self.peer_boot:#06x} → {boot:#06x}: "
                                      f"{self._other_run} frames in a row from the new one): its state no longer "
                                      "matches the servo loop's; restart the run")
        return False

    def _process(self, f: Frame, accept_new_boot: bool) -> None:
        kind = f.kind
        if kind in ("PLANT_STATUS", "HEARTBEAT_PLANT") and not self._ours(int(f.raw["BootId"]), accept_new_boot):
            return  # another node's, or not a frame at all: it keeps nothing alive either
        if kind == "SENS" and not accept_new_boot and self.peer_boot is not None \
                and int(f.raw["BootIdLow"]) != self.peer_boot & 0xFF:
            self.counters.other_boot += 1  # another node's values: never part of our answer
            return
        if kind in ("SENS", "TRUTH", "PLANT_STATUS", "HEARTBEAT_PLANT"):
            self._last_peer = time.monotonic()
        if kind == "HEARTBEAT_PLANT":  # alive (above); why the node latched amplifiers off, if it did
            self._peer_off_cause = int(f.raw["OffCause"])
        elif kind == "PLANT_SESSION":
            self._session_report(f.raw)
        elif kind == "SENS":
            if f.joint is not None and f.joint < self.n:
                self._sens[f.joint] = f.raw
            else:
                self.counters.foreign += 1
        elif kind == "TRUTH":
            if f.joint is not None and f.joint < self.n:
                self._truth[f.joint] = f.raw
        elif kind == "PLANT_STATUS":
            self._status(f, accept_new_boot)
        else:  # frames of another controller
            self.counters.foreign += 1

    def _session_report(self, r: dict[str, Any]) -> None:
        owner, active = int(r["Owner"]), bool(r["Active"])
        self.counters.peer_refused = int(r["Refused"])
        if not self._reset_acked:  # connecting: remember who holds the node if it refused us
            if active and owner != self.boot_id and int(r["RefusedBoot"]) == self.boot_id:
                self._refused_by = owner
            return
        if not (active and owner != self.boot_id):
            self._taken_by, self._taken_run = None, 0
            return
        # PLANT_SESSION names no sender: one frame that says so proves nothing (a stray frame);
        # the same owner in RESTART_EVIDENCE_FRAMES of them in a row does (the node repeats it
        # with every heartbeat). The node's own ResetAck of another controller (_status) is quicker.
        self.counters.other_boot += 1
        if owner == self._taken_by:
            self._taken_run += 1
        else:
            self._taken_by, self._taken_run = owner, 1
        if self._taken_run >= RESTART_EVIDENCE_FRAMES:
            raise SessionLostError(f"the plant node now serves another controller (boot id {owner:#06x}): "
                                   "its plant is no longer this run's; restart the run")

    def _status(self, f: Frame, accept_new_boot: bool) -> None:
        r = f.raw
        c = self.counters
        if r["ResetAck"]:
            acked, session = int(r["Tick"]), int(r["Session"])
            if acked != self.boot_id:  # another controller's RESET acknowledged
                if self._reset_acked and int(r["BootId"]) == self.peer_boot:
                    raise SessionLostError(f"the plant node acknowledged another controller's RESET (boot id "
                                           f"{acked:#06x}): its plant is no longer this run's; restart the run")
                return
            if self._reset_acked:
                if session == self.session and int(r["BootId"]) == self.peer_boot:
                    return  # our resent RESET acknowledged again (the node did not rebuild)
                raise PlantRestartedError(f"the plant node reset our session again (session {self.session} → "
                                          f"{session}): its state no longer matches the servo loop's")
            if int(r["NJoints"]) != self.n:
                raise PlantLinkError(f"the plant node has {int(r['NJoints'])} joints, this rig {self.n}: "
                                     "start both sides with the same --rig")
            if bool(r["FreeRunning"]) != self.free_running:
                mode = "free-running" if r["FreeRunning"] else "lockstep"
                raise PlantLinkError(f"the plant node runs {mode}: give this side --plant-mode {mode}, or restart "
                                     f"the node {'without' if r['FreeRunning'] else 'with'} --free-running")
            self.peer_boot = int(r["BootId"])
            self.session = session
            self._reset_acked = True
            self._sens.clear()
            self._truth.clear()
            self.counters.other_session += len(self._fresh)
            self._fresh.clear()  # answers of the node's previous session
            self.totals.reset()
            return
        if not self._reset_acked or int(r["Session"]) != self.session:  # not an answer to us
            c.other_session += 1
            self._sens.clear()
            self._truth.clear()
            return
        c.peer_missing_cmd, c.peer_dropped, c.peer_seq_jumps = int(r["MissingCmd"]), int(r["Dropped"]), int(
            r["SeqJumps"])
        c.peer_watchdog_tripped = bool(r["WatchdogTripped"])
        if c.peer_watchdog_tripped:
            # the node latched amplifiers off on its own: no current reaches them, so say so now,
            # with the node's reason (its heartbeat's), not as a current mismatch ticks later
            why = ("its enable watchdog or its command timeout" if not self._peer_off_cause else
                   OFF_CAUSES.get(self._peer_off_cause, "its enable watchdog or its command timeout").lower()
                   .replace("_", " ").replace("watchdog", "enable watchdog"))
            raise AmplifiersLatchedError(
                f"the plant node latched amplifiers off ({why}): the controller's commands came too late or "
                "stopped (docs/can.md, \"Command timeout\")")
        tick = int(r["Tick"])
        sens, truth = self._sens, self._truth
        self._sens, self._truth = {}, {}
        if r["StepError"]:
            raise PlantLinkError(f"the plant node could not step tick {tick}: its stderr says why "
                                 f"(`plant node: step {tick} failed: ...`)")
        seq = tick & 0xFF
        if len(sens) != self.n or any(sens.get(j, {}).get("Seq") != seq for j in range(self.n)):
            c.incomplete += 1
            return
        s = self.codec.sensors_from_frames(sens, truth, range(self.n), self.sensors_type)
        s.encoder = self.totals.recover(sens, range(self.n), s.encoder)
        self._fresh.append((tick, s))

    # --- the exchange ---------------------------------------------------------------------------
    def exchange(self, cmd, period_s: float, delay_s: float):
        now = time.monotonic()
        if not self.connected and self.failed is None:
            self.connect()
        self._heartbeat(now)
        tick = self.tick
        self.tick += 1
        raw = self.codec.command_raw(cmd)
        for m in self.codec.command_frames(raw, tick, self.boot_id):
            self.ep.send(m)
        self.ep.send(self.codec.sync_frame(raw, tick, period_s, delay_s, self.boot_id))
        if self.failed is not None:
            while True:  # read what came, without waiting; the failure is already reported
                try:
                    if not self._pump(0.0, accept_new_boot=True):
                        break
                except PlantLinkError:
                    pass
            self._fresh.clear()
            return self._held_sensors()
        try:
            got = self._collect_free() if self.free_running and self._held is not None else self._collect_tick(tick)
        except PlantLinkError as e:
            self.failed = e
            raise
        if got is not None:
            self._stale_run = 0
            self._held = got
            self.counters.answers += 1
            return got
        self._stale_run += 1
        self.counters.stale += 1
        silent = time.monotonic() - self._last_peer
        err: PlantLinkError | None = None
        if silent > self.heartbeat_timeout_s:
            err = PlantLostError(f"the plant node is silent for {silent:.2f} s (no answer, no heartbeat; "
                                 f"timeout {self.heartbeat_timeout_s:g} s) at tick {tick}")
        elif self._stale_run >= self.stale_ticks:
            err = StaleDataError(f"no fresh sensor data from the plant node for {self._stale_run} tick(s) "
                                 f"(limit {self.stale_ticks}) at tick {tick}")
        if err is not None:
            self.failed = err
            raise err
        return self._held_sensors()

    def _collect_tick(self, tick: int):
        """Lockstep (and the first free-running exchange): wait for the answer of ``tick``
        (free-running: for the first answer of our session, taking every one that came)."""
        t_end = time.monotonic() + self.answer_timeout_s
        while True:
            if self.free_running and self._fresh:
                return self._take_fresh()
            for k, (t_ans, s) in enumerate(self._fresh):
                if t_ans == tick:
                    self.counters.late += k
                    self._fresh = self._fresh[k + 1:]
                    return s
            if self._fresh and not self.free_running:
                self.counters.late += len(self._fresh)
                self._fresh.clear()
            now = time.monotonic()
            if now >= t_end:
                return None
            self._heartbeat(now)
            self._pump(min(t_end - now, self.heartbeat_s))

    def _collect_free(self):
        """Free-running: everything that arrived, without waiting; newest analog, summed encoder."""
        while self._pump(0.0):
            pass
        return self._take_fresh()

    def _take_fresh(self):
        """Every complete answer not yet consumed as one: the newest analog values, encoder
        events and switching of all of them (None when there is none)."""
        fresh = [s for _, s in self._fresh]
        if fresh and self.free_running:
            self.answer_step = self._fresh[-1][0]
        self._fresh.clear()
        if not fresh:
            return None
        if len(fresh) == 1:
            return fresh[0]
        newest = fresh[-1]
        newest.encoder = [merge_events([s.encoder[j] for s in fresh]) for j in range(self.n)]
        newest.switching = np.logical_or.reduce([np.asarray(s.switching, bool) for s in fresh])
        return newest

    def _held_sensors(self):
        """The last answer again, with no encoder motion (nothing new was observed)."""
        h = self._held
        if h is None:
            raise self.failed or StaleDataError("no sensor data from the plant node yet")
        return self.sensors_type(pot_v=h.pot_v, tach_v=h.tach_v, imon_v=h.imon_v, amp_fault=h.amp_fault,
                                 encoder=[QuadratureEvents(phase=e.phase) for e in h.encoder],
                                 switching=np.zeros(self.n, dtype=bool), truth=h.truth)

    def close(self) -> None:
        """End our session on the node (it idles the amplifiers and takes the next controller's
        RESET at once), then close the endpoint."""
        if self._reset_acked:
            self._reset_acked = False
            try:
                self.ep.send(self.codec.frame("CONTROL", Command=CONTROL_END, BootId=self.boot_id, NJoints=self.n))
            except can.CanError:  # a vanished bus: the node's controller timeout frees it instead
                pass
        self.ep.close()
