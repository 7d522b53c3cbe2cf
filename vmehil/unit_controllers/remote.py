"""Unit controllers in separate processes, on a CAN bus of their own (docs/melmalec.md).

The unit bus carries, per lockstep exchange ``r``:

    unit u  → CMD_Jjj (its joints, Seq = r), UNIT_SYNC (r, stopped, watchdog line)
    coordinator (once every running unit's UNIT_SYNC r is in, or the timeout declared it lost):
            steps the plant of every joint with the merged command (a lost unit's amplifiers
            off), → SENS_Jjj, TRUTH_Jjj (every joint), UNIT_ANSWER (r, stop cause, unit)

and around the run: UNIT_HEARTBEAT (a unit waiting to start, with its rig file's CRC-32),
UNIT_START (seed, ticks, digests, gains; one per unit, naming it and its boot id), UNIT_POS (each
unit's measured start: every unit plans the global motion from all of them), UNIT_STOP (the
coordinator's stop, or a refusal).

**Sessions.** Every node has a boot id, new at each start; the session is the coordinator's and
the units' it started with (UNIT_START: the coordinator's ``BootId``, and per unit the
``UnitBootId`` it heard in that unit's READY heartbeat). Every frame carries its sender's boot id
(CMD its low byte) and is checked against the session's: a unit starts only on a UNIT_START
naming its own boot id and, from then on, takes UNIT_ANSWER/UNIT_STOP only with the session's
coordinator boot id and UNIT_POS only with the boot id its START gave that unit; the
coordinator takes CMD/UNIT_SYNC/UNIT_TIMING only from the units it started. Frames of another
session are dropped and counted (``other_session``). A refusal before the start names the
refused unit's boot id (``UNIT_STOP.UnitBootId``). SENS carries the coordinator's low byte
(``BootIdLow``); TRUTH (ground truth for reports, never for the servo) carries none: it counts
only in an answer that a session UNIT_ANSWER completes. Two READY units with one name (two ``vmehil unit
--unit leg2``): the coordinator listens ``DUPLICATE_WINDOW_S`` past the last unit's first
heartbeat, refuses both (``REFUSED_DUPLICATE``) and every other unit (``RUN_REFUSED``), and the
run does not start.
The values travel through the DBC codec exactly as between a controller and the plant node
(quantizing twice is quantizing once), so the units' lockstep results equal the single
controller's, bit for bit.

Bounds (lockstep): a unit that stops hands in its stop with its commands for exchange ``r``;
every unit's answer ``r`` carries it: every unit safe-stops in that tick, the plant has every
amplifier off from exchange ``r + 1``. A unit silent for ``timeout_s`` (killed, hung) is declared
lost at the exchange it missed: the plant steps with its amplifiers off and every other unit
stops in that tick. A lost or late frame: a unit's commands incomplete at its UNIT_SYNC, or an
answer incomplete at UNIT_ANSWER, stops every unit in that exchange (no resend: lockstep never
waits longer than ``timeout_s``, and never hangs). The coordinator dead: every unit's answer
wait ends after ``timeout_s`` with a safe stop (``coordinator_lost``).
"""

from __future__ import annotations

import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from emulators.can.bus import Endpoint, open_bus, resolve
from emulators.can.can_plant_link import merge_events
from emulators.can.codec import CMD_SIGNALS, CanCodec, EncoderTotals, Frame, shared_codec
from emulators.can.dbc import (
    ID_CMD,
    ID_SENS,
    ID_TRUTH,
    ID_UNIT_ANSWER,
    ID_UNIT_HEARTBEAT,
    ID_UNIT_POS,
    ID_UNIT_START,
    ID_UNIT_STOP,
    ID_UNIT_SYNC,
    ID_UNIT_TIMING,
    UNIT_STOP_CAUSES,
    UNIT_TIMING_FIGURES,
)
from emulators.can.node import STATE_RUNNING
from emulators.plant import PlantCommand, PlantSensors
from emulators.plant_link import PlantLink, PlantLinkError, PlantLostError, StaleDataError
from emulators.signals import QuadratureEvents
from hal.config import read_limited
from servo.joint_groups import UnitSpec, rig_units, watchdog_unit
from servo.rig import RigSpec
from servo.runner import TickSeries, TimingStats, series_summary
from vmehil.errors import VmehilError
from vmehil.unit_controllers.hub import HubEvent, UnitLostError, UnitStopError

#: the unit bus's default channel per interface (never the plant bus's: both use SENS/CMD frames)
UNIT_CHANNELS = {"virtual": "vmehil-units", "udp_multicast": "239.74.163.3", "socketcan": "vcan1"}
#: the unit bus's UDP port on udp_multicast (python-can's default, the plant bus's, is 43113)
UNIT_PORT = 43114
ALL_UNITS = 255
STOP = {name: code for code, name in UNIT_STOP_CAUSES.items()}
START_TIMEOUT_S = 30.0
#: the coordinator listens this long after every unit has reported, for a second unit with one of
#: their names (a READY unit beats every 100 ms: 2.5 beats)
DUPLICATE_WINDOW_S = 0.25
#: UNIT_HEARTBEAT.State of a unit waiting to start
STATE_READY = 1
#: free-running: periods of wall time without news before a unit is lost (coordinator) / stops (unit)
FREE_STALE_TICKS = 5
#: UNIT_TIMING's signals and the keys of the runner's timing summary they carry (ms there, µs raw)
UNIT_TIMING_KEYS = {name: f"{name[:-3].lower()}_{name[-3:].lower()}_ms" for name in UNIT_TIMING_FIGURES}


def ms_to_us(ms: float) -> int:
    """A timing summary's milliseconds as UNIT_TIMING's raw microseconds."""
    return round(ms * 1e3)


def us_to_ms(us: int) -> float:
    """UNIT_TIMING's raw microseconds as the report's milliseconds."""
    return us / 1e3


class UnitRefused(VmehilError, RuntimeError):
    """A unit cannot join the run (another rig file or motion, started late, no coordinator)."""


class CoordinatorLostError(VmehilError, PlantLostError):
    """No answer from the coordinator within the timeout: the unit safe-stops."""

    cause = "coordinator_lost"


class PlantNodeLostError(VmehilError, PlantLostError):
    """The coordinator's plant (the CAN plant node, ``--plant can``) failed: every unit stops."""

    cause = "plant_lost"


class AnswerIncompleteError(VmehilError, StaleDataError):
    """A frame of the exchange was lost or late: every unit stops in that exchange."""

    cause = "answer_incomplete"


def file_digest(path: str | Path | None) -> int:
    """CRC-32 of a file's bytes (0 for no file): a unit and its coordinator must read the same."""
    return 0 if path is None else zlib.crc32(read_limited(path))


def unit_channel(interface: str | None, channel: str | None) -> tuple[str, str]:
    """The unit bus's interface and channel (its own default channel per interface)."""
    iface = resolve(interface, None)[0] if channel is None else resolve(interface, channel)[0]
    return iface, channel or UNIT_CHANNELS.get(iface) or resolve(iface, None)[1]


def unit_bus(interface: str | None, channel: str | None, log_path: str | None = None) -> UnitBus:
    iface, chan = unit_channel(interface, channel)
    # udp_multicast: a port of its own too. Linux delivers a group's datagrams to every socket
    # bound to the port that joined any group (IP_MULTICAST_ALL), so on python-can's port the
    # plant bus's frames would reach the units and the unit bus's the plant node
    extra: dict[str, Any] = {"port": UNIT_PORT} if iface == "udp_multicast" else {}
    return UnitBus(Endpoint(open_bus(iface, chan, **extra), set(), log_path=log_path))


class UnitBus:
    """One node's view of the unit bus: frames through the DBC codec."""

    def __init__(self, endpoint: Endpoint, codec: CanCodec | None = None) -> None:
        self.endpoint = endpoint
        self.codec = codec or shared_codec()
        #: identifiers worth decoding (None: all); a unit skips the other units' frames unread
        self.accept: set[int] | None = None

    def send(self, kind: str, **values: Any) -> None:
        self.endpoint.send(self.codec.frame(kind, **values))

    def send_all(self, frames: list) -> None:
        for m in frames:
            self.endpoint.send(m)

    def recv(self, timeout: float) -> Frame | None:
        """The next decodable frame, or ``None`` once ``timeout`` s have passed and nothing is
        waiting: frames skipped unread (not accepted, undecodable) never end the wait early, so
        ``recv(0.0)`` drains the queue up to the next frame worth reading (free-running)."""
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            m = self.endpoint.recv(max(0.0, deadline - time.monotonic()))
            if m is None:
                return None
            if self.accept is not None and m.arbitration_id not in self.accept:
                continue
            f = self.codec.try_decode(m)
            if f is not None:
                return f

    def close(self) -> None:
        self.endpoint.close()


def latch_newest(fresh: list[PlantSensors]) -> PlantSensors:
    """Several answers as one (free-running): the newest analog values, the encoder events and
    switching of all of them (no count is lost when two answers arrive in one tick)."""
    newest = fresh[-1]
    if len(fresh) > 1:
        n = len(newest.encoder)
        newest.encoder = [merge_events([s.encoder[j] for s in fresh]) for j in range(n)]
        newest.switching = np.logical_or.reduce([np.asarray(s.switching, bool) for s in fresh])
    return newest


# --- the unit's side -------------------------------------------------------------------------------
class UnitCanLink(PlantLink):
    """A unit controller's plant link over the unit bus (see the module docstring)."""

    def __init__(self, bus: UnitBus, unit: UnitSpec, number: int, boot_id: int, timeout_s: float,
                 *, session_boot: int | None = None, members: dict[int, int] | None = None) -> None:
        """``session_boot``: the coordinator's boot id (UNIT_START.BootId; None: any — tests of
        one unit without a session), ``members``: every unit's boot id of the session."""
        self.bus = bus
        self.session_boot = session_boot
        self.members = dict(members or {})
        #: frames of another session (another coordinator's, or a unit's the run did not start): dropped
        self.other_session = 0
        self._early_pos: dict[int, Frame] = {}  # UNIT_POS of units whose UNIT_START was not heard yet
        self.unit = unit
        self.number = number
        self.boot_id = boot_id
        self.timeout_s = timeout_s
        self.names = list(unit.joints)
        self.joints = list(unit.indices)
        self.stopped: Callable[[], str | None] = lambda: None
        self.exchanges = 0
        self.positions: dict[int, list[float]] = {}  #: UNIT_POS heard (unit number → thetas)
        self.dead = False  #: the coordinator is gone: exchanges no longer wait
        self._told = False
        self._last: PlantSensors | None = None
        self.stop_event: HubEvent | None = None
        #: free-running (UNIT_START.FreeRunning): answers are taken as they come, never waited for
        self.free_running = False
        #: free-running: periods of wall time without a fresh answer before a safe stop
        self.stale_ticks = FREE_STALE_TICKS
        self.stale = 0  #: free-running exchanges that found no fresh answer
        self.incomplete = 0  #: free-running answers missing one of the unit's SENS frames (dropped)
        self._fresh_at: float | None = None  # when the last fresh answer came (free-running)
        self._heard: float | None = None
        self._fresh: list[tuple[int, PlantSensors]] = []  # (plant step, its values), free-running
        #: the coordinator's running encoder totals: an answer missed (incomplete, dropped) loses no count
        self.totals = EncoderTotals()
        self._sens: dict[int, dict[str, Any]] = {}
        self._truth: dict[int, dict[str, Any]] = {}
        self._free_stop: tuple[Frame, int] | None = None
        # decode only what concerns this unit: its joints' answers, the coordinator's frames
        bus.accept = ({ID_SENS + j for j in self.joints} | {ID_TRUTH + j for j in self.joints}
                      | {ID_UNIT_ANSWER, ID_UNIT_STOP, ID_UNIT_POS, ID_UNIT_START})

    def of_session(self, f: Frame) -> bool:
        """Whether a frame of the coordinator (UNIT_ANSWER, UNIT_STOP) or of a unit (UNIT_POS) is
        this session's by its boot id; others' are dropped and counted (module docstring)."""
        if f.kind in ("UNIT_ANSWER", "UNIT_STOP"):
            ok = self.session_boot is None or int(f.raw["BootId"]) == self.session_boot
        elif f.kind == "SENS":
            ok = self.session_boot is None or int(f.raw["BootIdLow"]) == self.session_boot & 0xFF
        elif f.kind == "UNIT_POS":
            ok = not self.members or self.members.get(int(f.raw["Unit"])) == int(f.raw["BootId"])
        else:
            return True
        if not ok:
            self.other_session += 1
        return ok

    def take_position(self, f: Frame) -> bool:
        """A UNIT_POS: kept when its boot id is its unit's in the session, dropped and counted
        when not; False (nothing done) when that unit's UNIT_START has not been heard yet."""
        if self.members and int(f.raw["Unit"]) not in self.members:
            return False
        if self.of_session(f):
            self.positions[int(f.raw["Unit"])] = [float(f.raw[f"Theta{i}"]) for i in range(4)]
        return True

    def note(self, f: Frame) -> None:
        """A frame outside an answer: another unit's UNIT_START of this session (its boot id) or
        its UNIT_POS (kept for later when that unit's start has not been heard yet)."""
        if f.kind == "UNIT_START" and self.session_boot is not None and int(f.raw["BootId"]) == self.session_boot:
            u = int(f.raw["Unit"])
            self.members[u] = int(f.raw["UnitBootId"])
            early = self._early_pos.pop(u, None)
            if early is not None:
                self.take_position(early)
        elif f.kind == "UNIT_POS" and not self.take_position(f):
            self._early_pos[int(f.raw["Unit"])] = f  # the newest per unit number: bounded

    def exchange(self, cmd: PlantCommand, period_s: float, delay_s: float) -> PlantSensors:
        r = self.exchanges
        self.exchanges += 1
        if self.dead:
            return self._held()
        codec = self.codec
        raw = codec.command_raw(cmd)
        stopped = self.stopped()
        self.bus.send_all(codec.command_frames(raw, r, self.boot_id, joints=self.joints))
        self.bus.send("UNIT_SYNC", Exchange=r, Unit=self.number, Stopped=int(stopped is not None),
                      Watchdog=int(raw["Watchdog"]), BootId=self.boot_id)
        if self.free_running and r > 0:  # the power-up exchange (0) is lockstep in both modes
            return self._exchange_free(r, period_s)
        sens: dict[int, dict[str, Any]] = {}
        truth: dict[int, dict[str, Any]] = {}
        mine = set(self.joints)
        deadline = time.monotonic() + self.timeout_s
        answer: Frame | None = None
        while answer is None:
            f = self.bus.recv(deadline - time.monotonic())
            if f is None:
                self.dead = True
                raise CoordinatorLostError(f"unit {self.unit.name}: no answer from the coordinator for exchange {r} "
                                           f"within {self.timeout_s:g} s")
            if f.kind in ("UNIT_ANSWER", "UNIT_STOP", "SENS") and not self.of_session(f):
                continue
            if f.kind == "SENS" and f.joint in mine and int(f.raw["Seq"]) == r & 0xFF:
                sens[int(f.joint)] = f.raw
            elif f.kind == "TRUTH" and f.joint in mine:
                truth[int(f.joint)] = f.raw
            elif f.kind == "UNIT_ANSWER" and int(f.raw["Exchange"]) == r:
                answer = f
            elif f.kind == "UNIT_STOP" and int(f.raw["Unit"]) in (self.number, ALL_UNITS):
                cause = UNIT_STOP_CAUSES.get(int(f.raw["Cause"]), "UNKNOWN")
                if cause == "COORDINATOR_END":  # no answer will come any more
                    self.dead = True
                    raise CoordinatorLostError(f"unit {self.unit.name}: the coordinator ended the run at exchange {r}")
            else:
                self.note(f)
        stop = int(answer.raw["Stop"])
        if set(sens) != mine:
            if stop:  # a stop without the plant's values (the plant node was lost): the stop first
                self._stop(answer, r)
            missing = ", ".join(self.unit.joints[self.joints.index(j)] for j in sorted(mine - set(sens)))
            raise AnswerIncompleteError(f"unit {self.unit.name}: the answer to exchange {r} lacks {missing}")
        sensors = codec.sensors_from_frames(sens, truth, self.joints, PlantSensors)
        sensors.encoder = self.totals.recover(sens, self.joints, sensors.encoder)
        self._last = sensors
        if self.free_running:
            self.answer_step = int(answer.raw["PlantStep"])
        if stop:
            self._stop(answer, r)
        return sensors

    def _stop(self, answer: Frame, r: int) -> None:
        """Raise the coordinator's stop carried by ``answer`` (once: a unit is told one stop)."""
        if self._told:
            return
        self._told = True
        stop, who = int(answer.raw["Stop"]), int(answer.raw["StopUnit"])
        what = UNIT_STOP_CAUSES.get(stop, "UNKNOWN")
        self.stop_event = HubEvent(r, str(who), what)
        if what == "PLANT_LOST":
            raise PlantNodeLostError(f"the coordinator lost the plant node at exchange {r}: every unit stops")
        err = UnitLostError if what == "UNIT_LOST" else UnitStopError
        raise err(f"unit number {who}: {what.lower()} at exchange {r}: every unit stops")

    # --- free-running (docs/melmalec.md, "Free-running") -----------------------------------------
    @property
    def answer_lag_ticks(self) -> int:
        """Ticks the answers may lag the commands (the servo loop's current cross-check allows
        for them): lockstep 0; free-running ``stale_ticks`` — an answer older than that stops
        the unit anyway (two hops, unit → coordinator's step → unit, each on its own clock)."""
        return self.stale_ticks if self.free_running else 0

    def await_first_answer(self) -> None:
        """Free-running: say RUNNING (UNIT_HEARTBEAT State 2, every 100 ms) until the coordinator,
        which starts its clock once every unit has, publishes its first step (≤ ``timeout_s``)."""
        end = time.monotonic() + self.timeout_s
        counter = 0
        while not self._fresh:
            now = time.monotonic()
            if now >= end:
                self.dead = True
                raise CoordinatorLostError(f"unit {self.unit.name}: the coordinator did not start stepping within "
                                           f"{self.timeout_s:g} s")
            self.bus.send("UNIT_HEARTBEAT", State=STATE_RUNNING, Unit=self.number, Counter=counter & 0xFF,
                          Exchange=self.exchanges, BootId=self.boot_id)
            counter += 1
            beat_end = min(end, now + 0.1)
            while not self._fresh and (f := self.bus.recv(beat_end - time.monotonic())) is not None:
                self._take(f)
        self._fresh_at = time.monotonic()

    def _exchange_free(self, r: int, period_s: float) -> PlantSensors:
        """Take every complete answer that came since the last exchange, without waiting."""
        while (f := self.bus.recv(0.0)) is not None:
            self._take(f)
        if self._free_stop is not None:
            self._stop(*self._free_stop)
        fresh, self._fresh = self._fresh, []
        now = time.monotonic()
        if fresh:
            self._fresh_at = now
            self.answer_step = fresh[-1][0]
            self._last = latch_newest([s for _, s in fresh])
            return self._last
        self.stale += 1
        if self._fresh_at is None:  # never started (await_first_answer not called): start the clock now
            self._fresh_at = now
        quiet = now - self._fresh_at
        if quiet > self.stale_ticks * period_s:
            self.dead = True
            if now - (self._heard or self._fresh_at) > self.timeout_s:
                raise CoordinatorLostError(f"unit {self.unit.name}: nothing from the coordinator for "
                                           f"{quiet:.3f} s at exchange {r}")
            raise StaleDataError(f"unit {self.unit.name}: no fresh answer from the coordinator for "
                                 f"{quiet * 1e3:.0f} ms "
                                 f"(limit {self.stale_ticks} periods, {self.stale_ticks * period_s * 1e3:.0f} ms) "
                                 f"at exchange {r}")
        return self._held_still()

    def _take(self, f: Frame) -> None:
        """One frame of the free-running answer stream: an answer is complete at its UNIT_ANSWER
        when every joint of the unit has its SENS frame with that step's sequence number."""
        if f.kind in ("UNIT_ANSWER", "UNIT_STOP", "SENS") and not self.of_session(f):
            return
        self._heard = time.monotonic()
        if f.kind == "SENS" and f.joint is not None:
            self._sens[int(f.joint)] = f.raw
        elif f.kind == "TRUTH" and f.joint is not None:
            self._truth[int(f.joint)] = f.raw
        elif f.kind == "UNIT_ANSWER":
            step = int(f.raw["Exchange"])
            if int(f.raw["Stop"]) and self._free_stop is None:
                self._free_stop = (f, step)
            seq = step & 0xFF
            if all(int(self._sens.get(j, {}).get("Seq", -1)) == seq for j in self.joints):
                s = self.codec.sensors_from_frames(self._sens, self._truth, self.joints, PlantSensors)
                s.encoder = self.totals.recover(self._sens, self.joints, s.encoder)
                self._fresh.append((int(f.raw["PlantStep"]), s))
            else:
                self.incomplete += 1
            self._sens, self._truth = {}, {}
        elif f.kind == "UNIT_STOP" and int(f.raw["Unit"]) in (self.number, ALL_UNITS):
            if UNIT_STOP_CAUSES.get(int(f.raw["Cause"])) == "COORDINATOR_END":
                self.dead = True
                raise CoordinatorLostError(f"unit {self.unit.name}: the coordinator ended the run")
        else:
            self.note(f)

    def _held_still(self) -> PlantSensors:
        """The last answer again with no encoder motion (nothing new was observed)."""
        h = self._held()
        return PlantSensors(pot_v=h.pot_v, tach_v=h.tach_v, imon_v=h.imon_v, amp_fault=h.amp_fault,
                            encoder=[QuadratureEvents(phase=e.phase) for e in h.encoder],
                            switching=np.zeros(len(self.joints), dtype=bool), truth=h.truth)

    @property
    def codec(self) -> CanCodec:
        return self.bus.codec

    def _held(self) -> PlantSensors:
        if self._last is None:
            raise CoordinatorLostError(f"unit {self.unit.name}: no answer from the coordinator yet")
        return self._last

    def leave(self, why: str | None, *, ticks: int = 0, timing: dict[str, Any] | None = None) -> None:
        """Tell the coordinator this unit's run has ended (its outputs are safe), with its
        real-time figures (``timing``: :meth:`servo.runner.TimingStats.summary`) in UNIT_TIMING."""
        try:
            t = timing or {}
            self.bus.send("UNIT_TIMING", Unit=self.number, BootId=self.boot_id, Realtime=int(timing is not None),
                          Ticks=ticks,
                          Overruns=int(t.get("overruns", 0)),
                          **{name: ms_to_us(float(t.get(key, 0.0))) for name, key in UNIT_TIMING_KEYS.items()})
            self.bus.send("UNIT_SYNC", Exchange=self.exchanges, Unit=self.number, Left=1,
                          Stopped=int(why is not None), BootId=self.boot_id)
        except Exception:  # the bus is gone: the coordinator's timeout covers it
            pass


# --- the coordinator's side ----------------------------------------------------------------------
@dataclass
class CoordinatorTiming(TimingStats):
    """:class:`servo.runner.TimingStats` of the coordinator's steps (compute, lateness,
    overruns: free-running), and per step the plant's step, the answer's frames, the wait for
    every unit's commands (lockstep)."""

    plant_s: TickSeries = field(default_factory=TickSeries)
    answer_s: TickSeries = field(default_factory=TickSeries)
    wait_s: TickSeries = field(default_factory=TickSeries)

    def figures(self, period_s: float) -> dict[str, float | int]:
        out: dict[str, float | int] = {"steps": self.plant_s.total}
        if self.compute_s.total:
            out.update(self.summary(period_s))
        for name, series in (("plant", self.plant_s), ("answer", self.answer_s), ("wait", self.wait_s)):
            out.update(series_summary(name, series, period_s))
        return out


@dataclass
class CoordinatorOutcome:
    """What the coordinator saw: plant steps, the first stop, every event, amplifiers on per step."""

    exchanges: int = 0
    stop: HubEvent | None = None
    events: list[HubEvent] = field(default_factory=list)
    amps_on: list[int] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)
    #: the coordinator's own figures: per step the plant's step and the answer's frames; the
    #: round's wait for every unit (lockstep), wake-up lateness, compute and overruns (free-running)
    timing: CoordinatorTiming = field(default_factory=lambda: CoordinatorTiming())
    #: free-running: a unit's SYNC without its joint's CMD frame of that exchange (previous held)
    missing_cmd: int = 0
    #: per unit: the figures it reported when it left (UNIT_TIMING)
    unit_timing: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: frames of another session (a boot id the run did not start with): dropped
    other_session: int = 0


def coordinate(spec: RigSpec, bus: UnitBus, link: PlantLink, *, seed: int, n_ticks: int, boot_id: int,
               motion_path: str | None = None, gains: dict[str, float] | None = None,
               switch_off: bool | None = None, timeout_s: float = 2.0, start_timeout_s: float = START_TIMEOUT_S,
               stop_requested: Callable[[], bool] = lambda: False, free_running: bool = False,
               stale_ticks: int = FREE_STALE_TICKS) -> CoordinatorOutcome:
    """Wait for every unit of the rig, start them, and serve the plant until every unit has left
    (module docstring): in lockstep, or ``free_running`` on the wall clock (a unit silent for
    more than ``stale_ticks`` steps is lost; a unit without a fresh answer for ``stale_ticks``
    exchanges stops). Raises :class:`UnitRefused` when the units do not come."""
    units = rig_units(spec)
    if not units:
        raise UnitRefused(f"rig {spec.name} ({spec.path}) declares no [[rig.unit]] tables")
    # decode only the units' frames (udp_multicast loops our own back: skipped unread)
    bus.accept = {ID_CMD + j for j in range(spec.n_joints)} | {ID_UNIT_SYNC, ID_UNIT_HEARTBEAT, ID_UNIT_TIMING}
    digest = file_digest(spec.path)
    out = CoordinatorOutcome()
    ready: dict[int, int] = {}  # unit number → its boot id (its first READY heartbeat)
    heard: dict[int, set[int]] = {}  # unit number → every boot id a READY heartbeat gave it
    deadline = time.monotonic() + start_timeout_s
    settle_until: float | None = None
    while True:
        now = time.monotonic()
        if len(ready) == len(units):  # listen a little longer: a second unit of one name?
            settle_until = settle_until if settle_until is not None else now + DUPLICATE_WINDOW_S
            if now >= settle_until:
                break
            f = bus.recv(settle_until - now)
        else:
            f = bus.recv(deadline - now) if deadline > now else None
            if f is None:
                missing = ", ".join(u.name for i, u in enumerate(units) if i not in ready)
                raise UnitRefused(f"units {missing} did not report within {start_timeout_s:g} s "
                                  f"(start them: vmehil unit --rig {spec.name} --unit NAME)")
        if f is None or f.kind != "UNIT_HEARTBEAT" or int(f.raw["Unit"]) >= len(units):
            continue
        u, unit_boot = int(f.raw["Unit"]), int(f.raw["BootId"])
        if int(f.raw["State"]) != STATE_READY:  # a unit of a session already running
            out.other_session += 1
            continue
        if int(f.raw["RigDigest"]) != digest:
            bus.send("UNIT_STOP", Cause=STOP["REFUSED_RIG"], Unit=u, BootId=boot_id, UnitBootId=unit_boot)
            note = f"unit {units[u].name} refused: its rig file differs from {spec.path}"
            if note not in out.refused:
                out.refused.append(note)
            continue
        heard.setdefault(u, set()).add(unit_boot)
        ready.setdefault(u, unit_boot)
    twice = {u: sorted(boots) for u, boots in heard.items() if len(boots) > 1}
    if twice:
        for u, boots in twice.items():
            for b in boots:
                bus.send("UNIT_STOP", Cause=STOP["REFUSED_DUPLICATE"], Unit=u, BootId=boot_id, UnitBootId=b)
        for u, b in ready.items():
            if u not in twice:
                bus.send("UNIT_STOP", Cause=STOP["RUN_REFUSED"], Unit=u, BootId=boot_id, UnitBootId=b)
        which = "; ".join(f"{len(b)} units {units[u].name} (boot ids {', '.join(f'{x:#06x}' for x in b)})"
                          for u, b in twice.items())
        raise UnitRefused(f"the run does not start: {which} on the unit bus (one `vmehil unit --unit NAME` per "
                          "unit); every unit was refused")
    g = gains or {}
    for u, unit_boot in sorted(ready.items()):  # one start per unit, naming it: it starts on its own only
        bus.send("UNIT_START", Seed=seed, NTicks=n_ticks, RigDigest=digest, MotionDigest=file_digest(motion_path),
                 NUnits=len(units), SwitchOff=0 if switch_off is None else 2 if switch_off else 1,
                 GainsSet=int(bool(g)), BootId=boot_id, FreeRunning=int(free_running), StaleTicks=stale_ticks,
                 Unit=u, UnitBootId=unit_boot,
                 **{k.capitalize(): float(g.get(k, np.nan)) for k in ("kp", "kpi", "kv", "kvi")})
    try:
        server = _Server(spec, units, bus, link, out, n_ticks=n_ticks, boot_id=boot_id, timeout_s=timeout_s,
                         stale_ticks=stale_ticks, stop_requested=stop_requested, started=ready)
        _serve(server, free_running)
    finally:  # however the coordinator ends (its end, Ctrl-C, SIGTERM, an error): every unit stops now
        bus.send("UNIT_STOP", Cause=STOP["COORDINATOR_END"], Unit=ALL_UNITS, Exchange=out.exchanges,
                 BootId=boot_id)
    return out


class _Server:
    """The coordinator's side of the run: the plant served to the units, in lockstep or
    free-running (module docstring; docs/melmalec.md)."""

    def __init__(self, spec: RigSpec, units: list[UnitSpec], bus: UnitBus, link: PlantLink, out: CoordinatorOutcome,
                 *, n_ticks: int, boot_id: int, timeout_s: float, stale_ticks: int,
                 stop_requested: Callable[[], bool], started: dict[int, int]) -> None:
        self.spec, self.units, self.bus, self.link, self.out = spec, units, bus, link, out
        self.codec = bus.codec
        self.n = spec.n_joints
        self.n_ticks, self.boot_id, self.timeout_s, self.stale_ticks = n_ticks, boot_id, timeout_s, stale_ticks
        self.stop_requested, self.started = stop_requested, started
        self.owner = {j: u for u, unit in enumerate(units) for j in unit.indices}
        wd_name = watchdog_unit(spec, units)
        self.wd_unit = next((i for i, u in enumerate(units) if u.name == wd_name), None)
        self.idle = self.codec.command_raw(PlantCommand.idle(self.n))
        self.running = set(range(len(units)))
        self.stop: tuple[int, int, str] | None = None  # (exchange, unit number, cause)
        self.backlog: list[PlantSensors] = []  # a free-running node's answers not yet passed on
        self.totals = EncoderTotals()  # the running counts sent with every answer (UnitCanLink.totals)

    def of_session(self, f: Frame) -> bool:
        """Whether a unit's frame comes from a unit this run started (its boot id; a CMD's low
        byte): others' are dropped and counted (module docstring, "Sessions")."""
        raw = f.raw
        if f.kind == "CMD":
            u = self.owner.get(int(f.joint)) if f.joint is not None else None
            ok = u is not None and u in self.started and int(raw["BootIdLow"]) == self.started[u] & 0xFF
        elif f.kind in ("UNIT_SYNC", "UNIT_TIMING"):
            ok = self.started.get(int(raw["Unit"])) == int(raw["BootId"])
        else:
            ok = True
        if not ok:
            self.out.other_session += 1
        return ok

    def stop_now(self, r: int, u: int, cause: str, what: str) -> None:
        name = self.units[u].name if u < len(self.units) else "coordinator"
        self.out.events.append(HubEvent(r, name, what))
        if self.stop is None:
            self.stop = (r, u, cause)
            self.out.stop = HubEvent(r, name, what)

    def late_unit(self, f: Frame, r: int) -> None:
        """A heartbeat of a unit that was not started with the run: refused."""
        u = int(f.raw["Unit"])
        if u >= len(self.units) or self.started.get(u) == int(f.raw["BootId"]):
            return  # not a unit of the rig, or a started unit's last beat
        self.bus.send("UNIT_STOP", Cause=STOP["REFUSED_LATE"], Unit=u, Exchange=r, BootId=self.boot_id,
                      UnitBootId=int(f.raw["BootId"]))
        note = f"unit {self.units[u].name} refused: it reported at exchange {r}, after the start"
        if note not in self.out.refused:
            self.out.refused.append(note)

    def unit_figures(self, f: Frame) -> None:
        """A unit's UNIT_TIMING (sent as it leaves): its ticks, overruns and per-tick figures (ms)."""
        u = int(f.raw["Unit"])
        if u >= len(self.units):
            return
        fig: dict[str, Any] = {"ticks": int(f.raw["Ticks"]), "realtime": bool(int(f.raw["Realtime"]))}
        if fig["realtime"]:
            fig["overruns"] = int(f.raw["Overruns"])
            fig.update({key: us_to_ms(int(f.raw[name])) for name, key in UNIT_TIMING_KEYS.items()})
        self.out.unit_timing[self.units[u].name] = fig

    def collect_figures(self, wait_s: float = 0.5) -> None:
        """The UNIT_TIMING of units that left (or were lost) after the coordinator stopped
        listening: read for up to ``wait_s`` more, until every unit's has come."""
        end = time.monotonic() + wait_s
        while len(self.out.unit_timing) < len(self.units):
            f = self.bus.recv(end - time.monotonic())
            if f is None:
                return
            if f.kind == "UNIT_TIMING" and self.of_session(f):
                self.unit_figures(f)

    def left(self, f: Frame, r: int) -> None:
        u = int(f.raw["Unit"])
        self.running.discard(u)
        self.out.events.append(HubEvent(r, self.units[u].name, "left"))
        # a unit that ran to the end leaves after its n_ticks + 1 exchanges (power-up included)
        # and its end (a category-1 stop and 2 s watched, servo.runner.LockstepRunner.end_run);
        # fewer is no normal end either
        if int(f.raw["Stopped"]) or int(f.raw["Exchange"]) < self.n_ticks + 1:
            self.stop_now(r, u, "UNIT_STOPPED", "left before the run's end")

    def keep_plant(self) -> None:
        """While the units get ready: take a free-running plant node's answers (the motion of
        every step it makes meanwhile: its encoder counts, passed on with the first step's
        answer), with every amplifier off. An in-process or lockstep plant does not step."""
        if not getattr(self.link, "free_running", False) or self.stop is not None:
            return
        try:
            self.backlog.append(self.link.exchange(PlantCommand.idle(self.n), self.spec.period_s,
                                                   self.spec.computation_delay_s))
        except PlantLinkError as e:
            self.stop_now(0, ALL_UNITS, "PLANT_LOST", f"the plant failed: {type(e).__name__}: {e}")

    def step(self, r: int, raw: dict[str, Any], delay_s: float) -> None:
        """Step the plant with ``raw`` and answer exchange (free-running: step) ``r``."""
        out, codec, clock = self.out, self.codec, time.perf_counter
        if self.stop_requested():
            self.stop_now(r, ALL_UNITS, "COORDINATOR_STOPPED", "the coordinator was asked to stop")
        cmd = codec.command_from_raw(raw, PlantCommand)
        t0 = clock()
        try:
            sensors: PlantSensors | None = self.link.exchange(cmd, self.spec.period_s, delay_s)
        except PlantLinkError as e:  # the plant node is gone (or stale): every unit stops in this exchange
            sensors = None
            self.stop_now(r, ALL_UNITS, "PLANT_LOST", f"the plant failed: {type(e).__name__}: {e}")
        t1 = clock()
        if sensors is not None and self.backlog:  # the node's steps while the units got ready
            sensors = latch_newest([*self.backlog, sensors])
            self.backlog.clear()
        if sensors is not None:
            enabled = sensors.truth.get("amp_enabled")
            out.amps_on.append(int(np.count_nonzero(enabled)) if enabled is not None else -1)
            self.bus.send_all(codec.sensor_frames(codec.sensors_raw(sensors), r, truth=sensors.truth,
                                                  totals=self.totals.add(sensors.encoder), boot_id=self.boot_id))
        else:
            out.amps_on.append(-1)  # unknown: the plant did not answer
        stop = self.stop
        s_cause = STOP[stop[2]] if stop is not None and r >= stop[0] else 0
        plant_step = self.link.answer_step  # a free-running plant node's own step, else this exchange's
        self.bus.send("UNIT_ANSWER", Exchange=r, Stop=s_cause, StopUnit=stop[1] if stop is not None else 0,
                      BootId=self.boot_id, PlantStep=r if plant_step is None else plant_step)
        out.timing.plant_s.append(t1 - t0)
        out.timing.answer_s.append(clock() - t1)
        out.exchanges += 1

    def merged(self, cmds: dict[int, dict[str, Any]], units: set[int], r: int, *, missing_stops: bool) -> dict:
        """The plant's command: ``cmds`` for the joints of ``units``, every other joint idle (a
        lost or departed unit's amplifiers: off). A joint of ``units`` without a command: a stop
        (lockstep) or idle (free-running: its unit's previous commands were ``cmds``' already)."""
        raw = {k: np.array(v, copy=True) for k, v in self.idle.items()}
        for j in range(self.n):
            u = self.owner[j]
            if u not in units:
                continue
            c = cmds.get(j)
            if c is None:
                if missing_stops:
                    self.stop_now(r, u, "ANSWER_INCOMPLETE",
                                  f"joint {self.spec.joints[j].name}'s command frame missing")
                continue
            for k in CMD_SIGNALS:
                raw[k][j] = c[k]
        return raw

    # --- lockstep ------------------------------------------------------------------------------------
    def lockstep_round(self, r: int) -> bool:
        """Exchange ``r`` in lockstep: once every running unit's commands are in (or it is
        declared lost), step the plant and answer. False: no unit is left (nothing stepped)."""
        cmds: dict[int, dict[str, Any]] = {}
        synced: dict[int, int] = {}  # unit → watchdog level
        t0 = time.monotonic()
        deadline = t0 + self.timeout_s
        while not self.running <= set(synced):
            f = self.bus.recv(deadline - time.monotonic())
            if f is None:
                for u in sorted(self.running - set(synced)):
                    self.running.discard(u)
                    self.stop_now(r, u, "UNIT_LOST", f"lost: no commands for exchange {r} within {self.timeout_s:g} s")
                break
            if not self.of_session(f):
                continue
            if f.kind == "CMD" and f.joint is not None and f.joint < self.n and int(f.raw["Seq"]) == r & 0xFF:
                cmds[int(f.joint)] = f.raw
            elif f.kind == "UNIT_SYNC" and int(f.raw["Unit"]) in self.running:
                u = int(f.raw["Unit"])
                if int(f.raw["Left"]):
                    self.left(f, r)
                    continue
                if int(f.raw["Exchange"]) != r:
                    continue  # an old exchange's (it was declared lost meanwhile)
                synced[u] = int(f.raw["Watchdog"])
                if int(f.raw["Stopped"]):
                    self.stop_now(r, u, "UNIT_STOPPED", "stopped")
            elif f.kind == "UNIT_HEARTBEAT":
                self.late_unit(f, r)
            elif f.kind == "UNIT_TIMING":
                self.unit_figures(f)
        self.out.timing.wait_s.append(time.monotonic() - t0)
        if not synced:
            return False
        raw = self.merged(cmds, set(synced), r, missing_stops=True)
        raw["Watchdog"] = np.asarray(synced.get(self.wd_unit, 0) if self.wd_unit is not None else 0, dtype=np.int64)
        self.step(r, raw, 0.0 if r == 0 else self.spec.computation_delay_s)
        return True

    # --- free-running --------------------------------------------------------------------------------
    def free_run(self, first: int) -> None:
        """Step the plant every period on the wall clock with each unit's newest complete
        commands, from step ``first`` on, until every unit has left or is lost.

        The clock starts once every unit has said RUNNING (planned; ≤ ``timeout_s``, else it is
        lost); each unit starts its own clock at the first step's answer. A unit's CMD frames
        count once its UNIT_SYNC arrives (their ``Seq`` = its exchange); a unit whose last
        UNIT_SYNC is more than ``stale_ticks`` periods old (wall clock) is declared lost: its
        joints are idle (amplifiers off) from that step on and every unit is told to stop in
        that step's answer. The watchdog line gets one edge per step in which at least one
        arrived (as the free-running plant node feeds it). Nothing here waits past the next
        step's deadline."""
        spec, bus, out = self.spec, self.bus, self.out
        period = spec.period_s
        limit_s = self.stale_ticks * period
        clock = time.perf_counter
        pending: dict[int, dict[str, Any]] = {}  # CMD frames not yet confirmed by their unit's SYNC
        cmds: dict[int, dict[str, Any]] = {}  # every joint's newest confirmed command
        seen: dict[int, float] = {}  # unit → when its last SYNC arrived
        wd_level: int | None = None
        wd_edge = False
        wd_fed = 0
        step = first
        ready: set[int] = set()

        def take(f: Frame) -> None:
            nonlocal wd_level, wd_edge
            if not self.of_session(f):
                return
            if f.kind == "CMD" and f.joint is not None and f.joint < self.n:
                pending[int(f.joint)] = f.raw
            elif f.kind == "UNIT_SYNC" and int(f.raw["Unit"]) in self.running:
                u = int(f.raw["Unit"])
                if int(f.raw["Left"]):
                    self.left(f, step)
                    return
                seq = int(f.raw["Exchange"]) & 0xFF
                for j in self.units[u].indices:
                    c = pending.pop(j, None)
                    if c is not None and int(c["Seq"]) == seq:
                        cmds[j] = c
                    else:
                        out.missing_cmd += 1  # the joint keeps its previous command
                seen[u] = clock()
                if u == self.wd_unit:
                    level = int(f.raw["Watchdog"])
                    wd_edge = wd_edge or (wd_level is not None and level != wd_level)
                    wd_level = level
                if int(f.raw["Stopped"]):
                    self.stop_now(step, u, "UNIT_STOPPED", "stopped")
            elif f.kind == "UNIT_HEARTBEAT":
                u = int(f.raw["Unit"])
                if int(f.raw["State"]) == STATE_RUNNING and self.started.get(u) == int(f.raw["BootId"]):
                    ready.add(u)
                else:
                    self.late_unit(f, step)
            elif f.kind == "UNIT_TIMING":
                self.unit_figures(f)

        t_end = time.monotonic() + self.timeout_s
        keep_at = clock() + period
        while not self.running <= ready:
            now = time.monotonic()
            if now >= t_end:
                for u in sorted(self.running - ready):
                    self.running.discard(u)
                    self.stop_now(step, u, "UNIT_LOST", f"lost: not RUNNING within {self.timeout_s:g} s")
                break
            f = bus.recv(min(t_end - now, max(0.0, keep_at - clock())))
            if clock() >= keep_at:  # a free-running plant node steps meanwhile: keep its answers
                self.keep_plant()
                keep_at += period
            if f is not None:
                take(f)
        timing = out.timing
        t0 = clock()
        # a unit's first SYNC may take up to timeout_s (its clock starts at the first answer, after
        # its runner's start-up); from then on, stale_ticks periods
        first_by = t0 + self.timeout_s - limit_s
        seen.clear()  # from the clock's start: a unit not yet heard counts as heard at first_by
        i = 0
        while self.running:
            deadline = t0 + i * period
            while True:  # the units' frames until the step's deadline (all that is there, when late)
                left = deadline - clock()
                f = bus.recv(left) if left > 0 else bus.recv(0.0)
                if f is None:
                    break
                take(f)
            woke = clock()
            for u in sorted(self.running):
                if woke - seen.get(u, first_by) > limit_s:
                    self.running.discard(u)
                    quiet = woke - seen[u] if u in seen else woke - t0
                    self.stop_now(step, u, "UNIT_LOST", f"lost: no commands for {quiet * 1e3:.0f} ms "
                                                        f"(limit {self.stale_ticks} periods)")
            if not self.running:
                break
            raw = self.merged(cmds, self.running, step, missing_stops=False)
            if wd_edge:
                wd_fed ^= 1
                wd_edge = False
            raw["Watchdog"] = np.asarray(wd_fed if self.wd_unit in self.running else 0, dtype=np.int64)
            self.step(step, raw, spec.computation_delay_s)
            done = clock()
            timing.compute_s.append(done - woke)
            timing.lateness_s.append(max(0.0, woke - deadline))
            if done > deadline + period:
                timing.overruns += 1
            step += 1
            i += 1


def _serve(server: _Server, free_running: bool) -> None:
    r = 0
    while server.running:
        if not server.lockstep_round(r):
            break
        r += 1
        if free_running:  # after the power-up exchange (lockstep): the wall clock
            server.free_run(r)
            break
    # every unit has left or is lost: one last step with every amplifier off, so the plant ends
    # as the units' safe stops left their boards (a unit that stops ends its run at once and
    # does not send its safe outputs in another exchange)
    server.out.amps_on.append(_final_step(server.spec, server.link))
    server.collect_figures()


def _final_step(spec: RigSpec, link: PlantLink) -> int:
    """One last plant step with every amplifier off; how many amplifiers are on after it (-1:
    the plant did not answer — a lost plant node, whose command timeout latches them off)."""
    if getattr(link, "failed", None) is not None:
        return -1
    try:
        final = link.exchange(PlantCommand.idle(spec.n_joints), spec.period_s, spec.computation_delay_s)
    except PlantLinkError:
        return -1
    enabled = final.truth.get("amp_enabled")
    return int(np.count_nonzero(enabled)) if enabled is not None else -1


def unit_number(spec: RigSpec, name: str) -> int:
    for i, u in enumerate(rig_units(spec)):
        if u.name == name:
            return i
    raise UnitRefused(f"rig {spec.name} has no unit {name!r}")


#: why the coordinator refused a unit before the start (UNIT_STOP causes → the unit's message)
REFUSALS = {
    "REFUSED_RIG": "the coordinator refused this unit: its rig file differs from the coordinator's (start every "
                   "unit with the same --rig file)",
    "REFUSED_LATE": "the coordinator refused this unit: the run had already started (start the units before the "
                    "run starts)",
    "REFUSED_DUPLICATE": "the coordinator refused this unit: another unit of the same name is on the unit bus "
                         "(one `vmehil unit --unit NAME` per unit); the run does not start",
    "RUN_REFUSED": "the coordinator refused the run before it started (two units of one name on the unit bus; "
                   "its stderr says which)",
}


def wait_for_start(bus: UnitBus, *, number: int, digest: int, boot_id: int, timeout_s: float,
                   members: dict[int, int] | None = None) -> Frame:
    """Announce the unit (READY heartbeats every 100 ms) until a UNIT_START for it — naming this
    unit and its boot id; a refusal naming its boot id, or no coordinator within ``timeout_s``,
    raises :class:`UnitRefused`. ``members``: filled with every unit's boot id of the session (the
    UNIT_STARTs with the coordinator's boot id of ours), for checking the units' UNIT_POS."""
    deadline = time.monotonic() + timeout_s
    counter = 0
    starts: dict[int, dict[int, int]] = {}  # coordinator boot id → unit → boot id (STARTs heard)
    while time.monotonic() < deadline:
        bus.send("UNIT_HEARTBEAT", State=STATE_READY, Unit=number, Counter=counter & 0xFF, RigDigest=digest,
                 BootId=boot_id)
        counter += 1
        beat_end = min(deadline, time.monotonic() + 0.1)
        while True:
            f = bus.recv(beat_end - time.monotonic())
            if f is None:
                break
            if f.kind == "UNIT_STOP" and int(f.raw["Unit"]) in (number, ALL_UNITS) \
                    and int(f.raw["UnitBootId"]) == boot_id:
                refusal = REFUSALS.get(UNIT_STOP_CAUSES.get(int(f.raw["Cause"]), "UNKNOWN"))
                if refusal is not None:
                    raise UnitRefused(refusal)
            if f.kind == "UNIT_START":
                coord = int(f.raw["BootId"])
                starts.setdefault(coord, {})[int(f.raw["Unit"])] = int(f.raw["UnitBootId"])
                if int(f.raw["Unit"]) != number or int(f.raw["UnitBootId"]) != boot_id:
                    continue  # another unit's start, or another session's
                if int(f.raw["RigDigest"]) != digest:
                    raise UnitRefused("the coordinator's rig file differs from this unit's")
                if members is not None:
                    members.update(starts[coord])
                return f
    raise UnitRefused(f"no coordinator started the run within {timeout_s:g} s "
                      "(start one: vmehil coordinate --rig ...)")


def start_gains(start: Frame) -> dict[str, float]:
    if not int(start.raw["GainsSet"]):
        return {}
    return {k: float(start.raw[k.capitalize()]) for k in ("kp", "kpi", "kv", "kvi")
            if np.isfinite(float(start.raw[k.capitalize()]))}


def start_switch_off(start: Frame) -> bool | None:
    return {0: None, 1: False, 2: True}.get(int(start.raw["SwitchOff"]))

