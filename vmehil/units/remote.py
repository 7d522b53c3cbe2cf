"""Unit controllers in separate processes, on a CAN bus of their own (docs/melmalec.md).

The unit bus carries, per lockstep exchange ``r``:

    unit u  → CMD_Jjj (its joints, Seq = r), UNIT_SYNC (r, stopped, watchdog line)
    coordinator (once every running unit's UNIT_SYNC r is in, or the timeout declared it lost):
            steps the plant of every joint with the merged command (a lost unit's amplifiers
            off), → SENS_Jjj, TRUTH_Jjj (every joint), UNIT_ANSWER (r, stop cause, unit)

and around the run: UNIT_HEARTBEAT (a unit waiting to start, with its rig file's CRC-32),
UNIT_START (seed, ticks, digests, gains), UNIT_POS (each unit's measured start: every unit
plans the global motion from all of them), UNIT_STOP (the coordinator's stop, or a refusal).
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
from emulators.can.codec import CMD_SIGNALS, CanCodec, Frame, shared_codec
from emulators.can.dbc import (
    ID_SENS,
    ID_TRUTH,
    ID_UNIT_ANSWER,
    ID_UNIT_POS,
    ID_UNIT_START,
    ID_UNIT_STOP,
    UNIT_STOP_CAUSES,
)
from emulators.plant import PlantCommand, PlantSensors
from emulators.plant_link import PlantLink, PlantLinkError, PlantLostError, StaleDataError
from servo.rig import RigSpec
from servo.units import UnitSpec, rig_units, watchdog_unit
from vmehil.units.hub import HubEvent, UnitLostError, UnitStopError

#: the unit bus's default channel per interface (never the plant bus's: both use SENS/CMD frames)
UNIT_CHANNELS = {"virtual": "vmehil-units", "udp_multicast": "239.74.163.3", "socketcan": "vcan1"}
ALL_UNITS = 255
STOP = {name: code for code, name in UNIT_STOP_CAUSES.items()}
START_TIMEOUT_S = 30.0


class UnitRefused(RuntimeError):
    """A unit cannot join the run (another rig file or motion, started late, no coordinator)."""


class CoordinatorLostError(PlantLostError):
    """No answer from the coordinator within the timeout: the unit safe-stops."""

    cause = "coordinator_lost"


class PlantNodeLostError(PlantLostError):
    """The coordinator's plant (the CAN plant node, ``--plant can``) failed: every unit stops."""

    cause = "plant_lost"


class AnswerIncompleteError(StaleDataError):
    """A frame of the exchange was lost or late: every unit stops in that exchange."""

    cause = "answer_incomplete"


def file_digest(path: str | Path | None) -> int:
    """CRC-32 of a file's bytes (0 for no file): a unit and its coordinator must read the same."""
    return 0 if path is None else zlib.crc32(Path(path).read_bytes())


def unit_channel(interface: str | None, channel: str | None) -> tuple[str, str]:
    """The unit bus's interface and channel (its own default channel per interface)."""
    iface = resolve(interface, None)[0] if channel is None else resolve(interface, channel)[0]
    return iface, channel or UNIT_CHANNELS.get(iface) or resolve(iface, None)[1]


def unit_bus(interface: str | None, channel: str | None, log_path: str | None = None) -> UnitBus:
    iface, chan = unit_channel(interface, channel)
    return UnitBus(Endpoint(open_bus(iface, chan), set(), log_path=log_path))


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
        """The next decodable frame, or ``None`` once ``timeout`` s have passed."""
        deadline = time.monotonic() + max(0.0, timeout)
        while True:
            m = self.endpoint.recv(max(0.0, deadline - time.monotonic()))
            if m is None:
                return None
            if self.accept is not None and m.arbitration_id not in self.accept:
                if time.monotonic() >= deadline:
                    return None
                continue
            f = self.codec.try_decode(m)
            if f is not None:
                return f
            if time.monotonic() >= deadline:
                return None

    def close(self) -> None:
        self.endpoint.close()


# --- the unit's side -------------------------------------------------------------------------------
class UnitCanLink(PlantLink):
    """A unit controller's plant link over the unit bus (see the module docstring)."""

    def __init__(self, bus: UnitBus, unit: UnitSpec, number: int, boot_id: int, timeout_s: float) -> None:
        self.bus = bus
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
        # decode only what concerns this unit: its joints' answers, the coordinator's frames
        bus.accept = ({ID_SENS + j for j in self.joints} | {ID_TRUTH + j for j in self.joints}
                      | {ID_UNIT_ANSWER, ID_UNIT_STOP, ID_UNIT_POS, ID_UNIT_START})

    def _note(self, f: Frame) -> None:
        if f.kind == "UNIT_POS":
            self.positions[int(f.raw["Unit"])] = [float(f.raw[f"Theta{i}"]) for i in range(4)]

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
                self._note(f)
        stop = int(answer.raw["Stop"])
        if set(sens) != mine:
            if stop:  # a stop without the plant's values (the plant node was lost): the stop first
                self._stop(answer, r)
            missing = ", ".join(self.unit.joints[self.joints.index(j)] for j in sorted(mine - set(sens)))
            raise AnswerIncompleteError(f"unit {self.unit.name}: the answer to exchange {r} lacks {missing}")
        sensors = codec.sensors_from_frames(sens, truth, self.joints, PlantSensors)
        self._last = sensors
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

    @property
    def codec(self) -> CanCodec:
        return self.bus.codec

    def _held(self) -> PlantSensors:
        if self._last is None:
            raise CoordinatorLostError(f"unit {self.unit.name}: no answer from the coordinator yet")
        return self._last

    def leave(self, why: str | None) -> None:
        """Tell the coordinator this unit's run has ended (its outputs are safe)."""
        try:
            self.bus.send("UNIT_SYNC", Exchange=self.exchanges, Unit=self.number, Left=1,
                          Stopped=int(why is not None), BootId=self.boot_id)
        except Exception:  # the bus is gone: the coordinator's timeout covers it
            pass


# --- the coordinator's side ----------------------------------------------------------------------
@dataclass
class CoordinatorOutcome:
    """What the coordinator saw: plant steps, the first stop, every event, amplifiers on per step."""

    exchanges: int = 0
    stop: HubEvent | None = None
    events: list[HubEvent] = field(default_factory=list)
    amps_on: list[int] = field(default_factory=list)
    refused: list[str] = field(default_factory=list)


def coordinate(spec: RigSpec, bus: UnitBus, link: PlantLink, *, seed: int, n_ticks: int, boot_id: int,
               motion_path: str | None = None, gains: dict[str, float] | None = None,
               switch_off: bool | None = None, timeout_s: float = 2.0, start_timeout_s: float = START_TIMEOUT_S,
               stop_requested: Callable[[], bool] = lambda: False) -> CoordinatorOutcome:
    """Wait for every unit of the rig, start them, and serve the plant in lockstep until every
    unit has left (module docstring). Raises :class:`UnitRefused` when the units do not come."""
    units = rig_units(spec)
    if not units:
        raise UnitRefused(f"rig {spec.name} ({spec.path}) declares no [[rig.unit]] tables")
    codec = bus.codec
    # udp_multicast loops a node's own frames back: skip ours unread
    bus.endpoint.own_ids |= ({ID_SENS + j for j in range(spec.n_joints)} | {ID_TRUTH + j for j in range(spec.n_joints)}
                             | {ID_UNIT_ANSWER, ID_UNIT_STOP, ID_UNIT_START})
    digest = file_digest(spec.path)
    out = CoordinatorOutcome()
    ready: dict[int, int] = {}  # unit number → its boot id
    deadline = time.monotonic() + start_timeout_s
    while len(ready) < len(units):
        left = deadline - time.monotonic()
        f = bus.recv(left) if left > 0 else None
        if f is None:
            missing = ", ".join(u.name for i, u in enumerate(units) if i not in ready)
            raise UnitRefused(f"units {missing} did not report within {start_timeout_s:g} s "
                              f"(start them: vmehil unit --rig {spec.name} --unit NAME)")
        if f.kind != "UNIT_HEARTBEAT" or int(f.raw["Unit"]) >= len(units):
            continue
        u = int(f.raw["Unit"])
        if int(f.raw["RigDigest"]) != digest:
            bus.send("UNIT_STOP", Cause=STOP["REFUSED_RIG"], Unit=u, BootId=boot_id)
            note = f"unit {units[u].name} refused: its rig file differs from {spec.path}"
            if note not in out.refused:
                out.refused.append(note)
            continue
        ready[u] = int(f.raw["BootId"])
    g = gains or {}
    bus.send("UNIT_START", Seed=seed, NTicks=n_ticks, RigDigest=digest, MotionDigest=file_digest(motion_path),
             NUnits=len(units), SwitchOff=0 if switch_off is None else 2 if switch_off else 1,
             GainsSet=int(bool(g)), BootId=boot_id,
             **{k.capitalize(): float(g.get(k, np.nan)) for k in ("kp", "kpi", "kv", "kvi")})
    try:
        _serve(spec, units, bus, codec, link, out, n_ticks=n_ticks, boot_id=boot_id, timeout_s=timeout_s,
               stop_requested=stop_requested, started=ready)
    finally:  # however the coordinator ends (its end, Ctrl-C, SIGTERM, an error): every unit stops now
        bus.send("UNIT_STOP", Cause=STOP["COORDINATOR_END"], Unit=ALL_UNITS, Exchange=out.exchanges,
                 BootId=boot_id)
    return out


def _serve(spec: RigSpec, units: list[UnitSpec], bus: UnitBus, codec: CanCodec, link: PlantLink,
           out: CoordinatorOutcome, *, n_ticks: int, boot_id: int, timeout_s: float,
           stop_requested: Callable[[], bool], started: dict[int, int]) -> None:
    n = spec.n_joints
    owner = {j: u for u, unit in enumerate(units) for j in unit.indices}
    wd_name = watchdog_unit(spec, units)
    wd_unit = next((i for i, u in enumerate(units) if u.name == wd_name), None)
    idle = codec.command_raw(PlantCommand.idle(n))
    running = set(range(len(units)))
    stop: tuple[int, int, str] | None = None  # (exchange, unit number, cause)

    def stop_now(r: int, u: int, cause: str, what: str) -> None:
        nonlocal stop
        name = units[u].name if u < len(units) else "coordinator"
        out.events.append(HubEvent(r, name, what))
        if stop is None:
            stop = (r, u, cause)
            out.stop = HubEvent(r, name, what)

    r = 0
    while running:
        cmds: dict[int, dict[str, Any]] = {}
        synced: dict[int, int] = {}  # unit → watchdog level
        deadline = time.monotonic() + timeout_s
        while not running <= set(synced):
            f = bus.recv(deadline - time.monotonic())
            if f is None:
                for u in sorted(running - set(synced)):
                    running.discard(u)
                    stop_now(r, u, "UNIT_LOST", f"lost: no commands for exchange {r} within {timeout_s:g} s")
                break
            if f.kind == "CMD" and f.joint is not None and f.joint < n and int(f.raw["Seq"]) == r & 0xFF:
                cmds[int(f.joint)] = f.raw
            elif f.kind == "UNIT_SYNC" and int(f.raw["Unit"]) in running:
                u = int(f.raw["Unit"])
                if int(f.raw["Left"]):
                    running.discard(u)
                    out.events.append(HubEvent(r, units[u].name, "left"))
                    if int(f.raw["Stopped"]) or int(f.raw["Exchange"]) < n_ticks + 1:
                        stop_now(r, u, "UNIT_STOPPED", "left before the run's end")
                    continue
                if int(f.raw["Exchange"]) != r:
                    continue  # an old exchange's (it was declared lost meanwhile)
                synced[u] = int(f.raw["Watchdog"])
                if int(f.raw["Stopped"]):
                    stop_now(r, u, "UNIT_STOPPED", "stopped")
            elif (f.kind == "UNIT_HEARTBEAT" and int(f.raw["Unit"]) < len(units)
                  and started.get(int(f.raw["Unit"])) != int(f.raw["BootId"])):  # not a started unit's last beat
                u = int(f.raw["Unit"])
                bus.send("UNIT_STOP", Cause=STOP["REFUSED_LATE"], Unit=u, Exchange=r, BootId=boot_id)
                note = f"unit {units[u].name} refused: it reported at exchange {r}, after the start"
                if note not in out.refused:
                    out.refused.append(note)
        if not synced:
            # every unit has left or is lost: one last step with every amplifier off, so the
            # plant ends as the units' safe stops left their boards (a unit that stops ends its
            # run at once and does not send its safe outputs in another exchange)
            out.amps_on.append(_final_step(spec, link))
            break
        if stop_requested():
            stop_now(r, ALL_UNITS, "COORDINATOR_STOPPED", "the coordinator was asked to stop")
        raw = {k: np.array(v, copy=True) for k, v in idle.items()}
        for j in range(n):
            u = owner[j]
            if u not in synced:
                continue  # a lost or departed unit's amplifiers: off
            c = cmds.get(j)
            if c is None:
                stop_now(r, u, "ANSWER_INCOMPLETE", f"joint {spec.joints[j].name}'s command frame missing")
                continue
            for k in CMD_SIGNALS:
                raw[k][j] = c[k]
        raw["Watchdog"] = np.asarray(synced.get(wd_unit, 0) if wd_unit is not None else 0, dtype=np.int64)
        cmd = codec.command_from_raw(raw, PlantCommand)
        try:
            sensors: PlantSensors | None = link.exchange(cmd, spec.period_s,
                                                         0.0 if r == 0 else spec.computation_delay_s)
        except PlantLinkError as e:  # the plant node is gone (or stale): every unit stops in this exchange
            sensors = None
            stop_now(r, ALL_UNITS, "PLANT_LOST", f"the plant failed: {type(e).__name__}: {e}")
        if sensors is not None:
            enabled = sensors.truth.get("amp_enabled")
            out.amps_on.append(int(np.count_nonzero(enabled)) if enabled is not None else -1)
            bus.send_all(codec.sensor_frames(codec.sensors_raw(sensors), r, truth=sensors.truth))
        else:
            out.amps_on.append(-1)  # unknown: the plant did not answer
        s_cause = STOP[stop[2]] if stop is not None and r >= stop[0] else 0
        bus.send("UNIT_ANSWER", Exchange=r, Stop=s_cause, StopUnit=stop[1] if stop is not None else 0,
                 BootId=boot_id)
        out.exchanges += 1
        r += 1


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


def wait_for_start(bus: UnitBus, *, number: int, digest: int, boot_id: int, timeout_s: float) -> Frame:
    """Announce the unit (READY heartbeats every 100 ms) until UNIT_START; a refusal or no
    coordinator within ``timeout_s`` raises :class:`UnitRefused`."""
    deadline = time.monotonic() + timeout_s
    counter = 0
    while time.monotonic() < deadline:
        bus.send("UNIT_HEARTBEAT", State=1, Unit=number, Counter=counter & 0xFF, RigDigest=digest, BootId=boot_id)
        counter += 1
        beat_end = min(deadline, time.monotonic() + 0.1)
        while True:
            f = bus.recv(beat_end - time.monotonic())
            if f is None:
                break
            if f.kind == "UNIT_STOP" and int(f.raw["Unit"]) in (number, ALL_UNITS):
                cause = UNIT_STOP_CAUSES.get(int(f.raw["Cause"]), "UNKNOWN")
                if cause == "REFUSED_RIG":
                    raise UnitRefused("the coordinator refused this unit: its rig file differs from the "
                                      "coordinator's (start every unit with the same --rig file)")
                if cause == "REFUSED_LATE":
                    raise UnitRefused("the coordinator refused this unit: the run had already started "
                                      "(start the units before the run starts)")
            if f.kind == "UNIT_START":
                if int(f.raw["RigDigest"]) != digest:
                    raise UnitRefused("the coordinator's rig file differs from this unit's")
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

