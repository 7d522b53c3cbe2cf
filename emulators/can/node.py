"""The plant node: the plant (motors, Harmonic Drives, sensors, amplifier power stages) as its own
node on a CAN bus.

Protocol (frames of ``vmehil.dbc``; see ``docs/can.md``):

* **CONTROL** ``RESET`` (from the controller's link when it connects): rebuild the plant with
  the given seed, at rest; answer ``PLANT_STATUS`` with ``ResetAck = 1`` (its ``Tick`` = the
  RESET's ``BootId``) and open a **session** for that controller boot id (numbered 1..15 in
  ``PLANT_STATUS.Session``). **Sessions**: while one runs, CONTROL, SYNC and CMD frames of
  other boot ids (SYNC carries ``BootId``, CMD its low byte) are refused and counted
  (``PLANT_SESSION.Refused``), never obeyed; a RESET of another boot id is accepted only when
  the session is over: its owner sent ``END`` or has been silent (no frame at all) for
  ``controller_timeout_s``. A RESET the owner resends before commanding anything (same seed) is
  acknowledged again without rebuilding the plant. Without a session nothing is obeyed but a
  RESET.
* **CMD_Jxx** frames set each joint's command (held until the next one).
* **Lockstep** — on **SYNC** (tick ``k``, period, delay) the node advances the plant exactly one
  period with the commands whose ``Seq`` is ``k mod 256`` (a joint without one keeps its previous
  command: counted in ``MissingCmd``), then answers ``SENS_Jxx`` (and ``TRUTH_Jxx``) with
  ``Seq = k mod 256`` and finally ``PLANT_STATUS`` with ``Tick = k``, which marks the answer
  complete.
* **Free-running** — the node steps on the wall clock every ``period_s`` with the newest
  commands and publishes the same answer with ``Tick`` = its own step count. If the controller
  falls silent for ``controller_timeout_s`` the node disables every amplifier (idle command)
  until it hears from the controller again.
* **Command timeout** (both modes; ``command_timeout_s``, ``vmehil plant-node
  --command-timeout``): when no CONTROL or SYNC has arrived for that long of wall-clock time,
  the node latches every enabled amplifier off (the plant's enable-watchdog latch, cause
  ``command_timeout``; re-armed by an enable rising while commands come again) and engages every
  holding brake (the wall-clock silence outlasts their engage delay). ``"auto"`` (the default of
  ``vmehil plant-node``) follows the rig's period and the link's measured lateness
  (:meth:`PlantNode.effective_command_timeout_s`). A clean ``END`` disarms it until the next
  command. In lockstep
  simulated time stops with the controller, so the plant's own charge-pump watchdog cannot run
  out: this is the amplifier side's watchdog on the clock that still runs.
* **HEARTBEAT_PLANT** every ``heartbeat_s`` of wall-clock time, and at once when the amplifier
  state changes (a trip, the command timeout): the node's boot id and the amplifiers' state
  (how many are on, how many latched off and why, whether the command timeout is in force).

Unknown, malformed or out-of-range frames are counted (``PLANT_STATUS.Dropped``) and dropped;
SYNC ticks that are not the previous + 1 are counted (``SeqJumps``) and stepped anyway.
"""

from __future__ import annotations

import logging
import math
import os
import signal
import threading
import time
from collections import deque
from collections.abc import Callable, Collection
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import can
import numpy as np

from emulators.can.bus import Endpoint
from emulators.can.codec import CanCodec, EncoderTotals
from emulators.can.dbc import (
    CONTROL_END,
    CONTROL_RESET,
    ID_HEARTBEAT_PLANT,
    ID_SENS,
    ID_SESSION,
    ID_STATUS,
    ID_TRUTH,
    MAX_JOINTS,
)
from emulators.faults import FaultInjectable
from emulators.plant.amplifier import WATCHDOG_COMMAND_TIMEOUT, cause_names

log = logging.getLogger(__name__)

#: ``command_timeout_s=AUTO``: the command timeout follows the rig's period and the link's lateness
AUTO = "auto"
AUTO_TIMEOUT_PERIODS = 25  #: the automatic timeout's floor, in servo periods (0.2 s at 125 Hz)
AUTO_LATENESS_FACTOR = 3.0  #: … or this many times the longest recent gap between commands
AUTO_GAP_WINDOW = 500  #: the gaps it looks back over (4 s at 125 Hz)
AUTO_TIMEOUT_MAX_S = 1.0  #: and never longer than this (a dead controller must still be caught)

PLANT_IDS = {ID_STATUS, ID_HEARTBEAT_PLANT, ID_SESSION} | {ID_SENS + j for j in range(MAX_JOINTS)} | {
    ID_TRUTH + j for j in range(MAX_JOINTS)}
STATE_READY, STATE_RUNNING, STATE_STOPPED, STATE_FAULT = 1, 2, 3, 4


def new_boot_id() -> int:
    """A 16-bit identifier that differs between node starts (process id and start time)."""
    return (os.getpid() * 7919 ^ time.time_ns() // 1000) & 0xFFFF


@dataclass
class NodeSpec:
    """What a plant node needs from a rig file: the plant tables, joint names and timing."""

    name: str
    table: Any
    names: list[str]
    period_s: float
    delay_s: float

    @property
    def n_joints(self) -> int:
        return len(self.names)


def node_spec(rig: str | None, *, foreign_keys: Collection[str] | None = None) -> NodeSpec:
    """Read a rig preset name or file for the plant node (``[rig]``, ``[plant]``, ``[[joint]]``;
    the ``[[joint]]`` keys of the file's other readers, if the caller knows them, in
    ``foreign_keys``: see :mod:`emulators.plant.params`)."""
    from emulators.plant import plant_params_from_config
    from emulators.presets import resolve_rig
    from hal.config import load_toml

    path = resolve_rig(rig)
    table = load_toml(path)
    r = table.table("rig", {})
    rate = r.get_float("servo_rate_hz", 125.0, min=1.0, max=10_000.0)
    params = plant_params_from_config(table, foreign_keys=foreign_keys)
    return NodeSpec(r.get_str("name", Path(path).stem), table, [j.name for j in params.joints], 1.0 / rate,
                    r.get_float("computation_delay_s", 0.001, min=0.0))


@dataclass
class NodeCounters:
    steps: int = 0
    missing_cmd: int = 0
    dropped: int = 0
    seq_jumps: int = 0
    step_errors: int = 0
    resets: int = 0
    controller_lost: int = 0
    command_timeouts: int = 0  #: times the command timeout came into force
    watchdog_trips: int = 0  #: amplifiers latched off (by the watchdog line or the command timeout)
    bad_sync: int = 0  #: SYNC frames refused: a period other than the rig's, or a delay outside it
    refused: int = 0  #: CONTROL, SYNC and CMD frames refused: not from the session's owner (or no session)
    refused_resets: int = 0  #: of them, RESETs from another controller while the session runs
    duplicate_resets: int = 0  #: RESETs resent by the owner before it commanded: acknowledged again, not rebuilt


@runtime_checkable
class AmplifierSide(Protocol):
    """A plant whose amplifiers have the enable-watchdog latch (:class:`emulators.plant.Plant`).
    Plants without it (the transport tests' toy) report their enable lines and cannot be held off."""

    def amplifier_enabled(self) -> np.ndarray: ...

    def amplifier_watchdog_cause(self) -> np.ndarray: ...

    def hold_amplifiers_off(self, cause: int) -> np.ndarray: ...


@dataclass(frozen=True)
class AmplifierState:
    """The amplifier side as the node reports it (per joint arrays)."""

    enabled: np.ndarray  #: output stage on
    cause: np.ndarray  #: why latched off (``WATCHDOG_*`` bits; 0 = not latched)
    command_timeout: bool  #: no CONTROL/SYNC for longer than the command timeout, now

    @property
    def tripped(self) -> np.ndarray:
        return self.cause != 0

    @property
    def off_cause(self) -> int:
        """The union of the latched amplifiers' causes."""
        return int(np.bitwise_or.reduce(self.cause)) if self.cause.size else 0

    def as_dict(self, names: list[str]) -> dict[str, Any]:
        """For the node's ``--json`` summary: per joint on/off and why."""
        return {
            "enabled": int(np.count_nonzero(self.enabled)),
            "joints": len(names),
            "command_timeout": self.command_timeout,
            "per_joint": {name: {"enabled": bool(on), "latched_off_by": cause_names(int(c))}
                          for name, on, c in zip(names, self.enabled, self.cause, strict=True)},
        }

    def describe(self, names: list[str]) -> str:
        """One line for the log: ``amplifiers 0/7 enabled; 7 latched off (command_timeout)``."""
        text = f"amplifiers {int(np.count_nonzero(self.enabled))}/{len(names)} enabled"
        if self.tripped.any():
            text += f"; {int(np.count_nonzero(self.tripped))} latched off ({', '.join(cause_names(self.off_cause))})"
        if self.command_timeout:
            text += "; command timeout in force"
        return text


class PlantNode(FaultInjectable):
    """Serves one plant on a bus.

    Args:
        endpoint: the node's :class:`~emulators.can.bus.Endpoint` (or a python-can bus).
        plant_factory: ``seed -> plant`` (an object with ``step_period(cmd, period_s, delay_s)``).
        n_joints: joints of the plant (must match the controller's).
        seed: seed of the plant built at start (a controller's RESET brings its own).
        free_running: step on the wall clock instead of on SYNC.
        period_s: free-running step (s).
        delay_s: free-running computation delay passed to the plant (s).
        heartbeat_s: heartbeat interval (s, wall clock).
        controller_timeout_s: free-running: silence after which amplifiers are disabled (s).
        command_timeout_s: both modes: no CONTROL/SYNC for this long latches every enabled
            amplifier off (s; ``"auto"``: follows the period and the measured lateness, what
            ``vmehil plant-node`` uses by default; ``None``: off — the default for a node in the
            controller's own process, which dies with it).
        command_type: the plant's command class (default :class:`emulators.plant.PlantCommand`).
        names: joint names for the log (default ``joint0``, ``joint1``, …).
        clock: monotonic wall clock (s), for the timeouts.

    Fault ``dead``: the node process has died — it answers nothing and sends no heartbeat (frames
    reaching it are read and ignored, as a dead node's controller sees nothing of them either).
    """

    FAULTS = {  # noqa: RUF012 - the FaultInjectable catalogue
        "dead": "the plant node dies: no answers, no heartbeats from now on",
    }

    def __init__(self, endpoint: Endpoint | can.BusABC, plant_factory: Callable[[int], Any], n_joints: int, *,
                 seed: int = 0, free_running: bool = False, period_s: float = 0.008, delay_s: float = 0.0,
                 heartbeat_s: float = 0.1, controller_timeout_s: float = 0.5,
                 command_timeout_s: float | str | None = None,
                 command_type: Callable[..., Any] | None = None, codec: CanCodec | None = None,
                 boot_id: int | None = None, names: list[str] | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if command_timeout_s is not None and command_timeout_s != AUTO and not (
                isinstance(command_timeout_s, int | float) and command_timeout_s > 0):
            raise ValueError(f"command_timeout_s must be > 0, {AUTO!r} or None, got {command_timeout_s!r}")
        self.ep = endpoint if isinstance(endpoint, Endpoint) else Endpoint(endpoint, PLANT_IDS, owns_bus=False)
        self.ep.own_ids |= PLANT_IDS
        self.codec = codec or CanCodec()
        self.codec.check_joints(n_joints)
        self.n = n_joints
        self.names = list(names) if names is not None else [f"joint{j}" for j in range(n_joints)]
        if len(self.names) != n_joints:
            raise ValueError(f"{len(self.names)} names for {n_joints} joints")
        self.factory = plant_factory
        self.free_running = free_running
        self.period_s = float(period_s)
        self.delay_s = float(delay_s)
        self.heartbeat_s = heartbeat_s
        self.controller_timeout_s = controller_timeout_s
        self.command_timeout_s = command_timeout_s
        self.clock = clock
        if command_type is None:
            from emulators.plant import PlantCommand

            command_type = PlantCommand
        self.command_type = command_type
        self.boot_id = new_boot_id() if boot_id is None else boot_id & 0xFFFF
        self.counters = NodeCounters()
        self._hb_counter = 0
        self._next_hb = 0.0
        self._last_controller: float | None = None  # monotonic time of the last controller frame
        self._last_command: float | None = None  # monotonic time of the last CONTROL or SYNC
        #: the latest gaps between two CONTROL/SYNC (wall clock): the link's measured lateness, which
        #: the automatic command timeout follows
        self._gaps: deque[float] = deque(maxlen=AUTO_GAP_WINDOW)
        self.command_timed_out = False  #: the command timeout is in force
        self.last_silence_s: float | None = None  #: the silence that brought the last command timeout
        self.state = STATE_READY
        self.session_owner: int | None = None  #: boot id of the controller whose session runs
        self.session_no = 0  #: its number (1..15; 0: no session)
        self._sessions = 0  # sessions opened
        self._owner_seen: float | None = None  # clock of the owner's last frame
        self._session_commanded = False  # the owner sent CMD/SYNC since its RESET
        self.refused_boot: int | None = None  #: boot id of the last controller refused
        self._refused_boots: set[int] = set()  # controllers whose refused RESET was logged
        self._refused_at_open = 0  # counters.refused when the session opened
        self._reset_state(seed)

    # --- state ----------------------------------------------------------------------------------
    def _idle_raw(self) -> dict[str, np.ndarray]:
        z = np.zeros(self.n, dtype=np.int64)
        return {"AmpCommand": z.copy(), "PwmDuty": z.copy(), "AmpEnable": z.copy(), "FaultReset": z.copy(),
                "PwmDirection": np.ones(self.n, dtype=np.int64), "Brake": z.copy(), "HoldingBrake": z.copy()}

    def _reset_state(self, seed: int) -> None:
        self.seed = int(seed)
        self.plant = self.factory(self.seed)
        self.cmd_raw = self._idle_raw()
        self.cmd_seq = np.full(self.n, -1)
        self.last_tick: int | None = None
        self.counters.steps = 0
        self.totals = EncoderTotals()  # every answer's running counts: a receiver that misses one loses none
        self._watchdog_rx = 0  # the enable-watchdog line in the last SYNC
        self._watchdog_edge = False  # an edge arrived since the last step
        self._watchdog_fed = 0  # the line as the plant sees it
        self._trips_seen = 0  # latched amplifiers of this plant already reported

    # --- I/O ------------------------------------------------------------------------------------
    def _send(self, msg: can.Message) -> None:
        try:
            self.ep.send(msg)
        except can.CanError as e:  # a full queue or a vanished bus: count, keep serving
            self.counters.dropped += 1
            log.warning("plant node: send failed: %s", e)

    def _status(self, tick: int, *, reset_ack: bool = False, step_error: bool = False) -> None:
        c = self.counters
        self._send(self.codec.frame(
            "PLANT_STATUS", Tick=tick & 0xFFFFFFFF, BootId=self.boot_id, NJoints=self.n,
            FreeRunning=int(self.free_running), StepError=int(step_error), ResetAck=int(reset_ack),
            Session=self.session_no,
            WatchdogTripped=int(self.amplifiers().tripped.any()),
            MissingCmd=c.missing_cmd, Dropped=c.dropped + self._codec_dropped(), SeqJumps=c.seq_jumps,
            Steps=c.steps & 0xFFFF))

    def dropped_total(self) -> int:
        """Frames dropped: malformed, unknown, out of range (codec) and foreign (node)."""
        return self.counters.dropped + self._codec_dropped()

    def _codec_dropped(self) -> int:
        k = self.codec.counters
        return k.unknown_id + k.wrong_length + k.undecodable + k.out_of_range

    def heartbeat(self, now: float | None = None, *, force: bool = False) -> None:
        """Send the heartbeat if it is due (or at once with ``force``: the amplifier state changed)."""
        now = self.clock() if now is None else now
        if (now < self._next_hb and not force) or self.fault("dead") is not None:
            return
        self._next_hb = now + self.heartbeat_s
        self._hb_counter = (self._hb_counter + 1) & 0xFF
        amps = self.amplifiers()
        self._send(self.codec.frame("HEARTBEAT_PLANT", State=self.state, BootId=self.boot_id,
                                    Counter=self._hb_counter, Tick=(self.last_tick or 0) & 0xFFFFFFFF,
                                    AmpsEnabled=int(np.count_nonzero(amps.enabled)),
                                    WatchdogTripped=int(np.count_nonzero(amps.tripped)), OffCause=amps.off_cause,
                                    CommandTimeout=int(amps.command_timeout)))
        self._session_frame()

    def _session_frame(self) -> None:
        """PLANT_SESSION: who owns the node, and what was refused."""
        c = self.counters
        self._send(self.codec.frame("PLANT_SESSION", Owner=self.session_owner or 0, Session=self.session_no,
                                    Active=int(self.session_owner is not None), Open=int(self.session_open()),
                                    Refused=c.refused, RefusedBoot=self.refused_boot or 0))

    # --- sessions -------------------------------------------------------------------------------
    def session_open(self, now: float | None = None) -> bool:
        """True when a RESET from another controller would be accepted: no session runs, or its
        owner has been silent (no frame at all) for ``controller_timeout_s``."""
        if self.session_owner is None or self._owner_seen is None:
            return True
        now = self.clock() if now is None else now
        return now - self._owner_seen > self.controller_timeout_s

    def _from_owner(self, kind: str, raw: dict[str, Any]) -> bool:
        """The frame comes from the session's owner (CMD carries the low byte of its boot id)."""
        if self.session_owner is None:
            return False
        if kind == "CMD":
            return int(raw["BootIdLow"]) == self.session_owner & 0xFF
        return int(raw["BootId"]) == self.session_owner

    def _refuse(self, kind: str, boot: int, *, reset: bool = False) -> None:
        c = self.counters
        c.refused += 1
        self.refused_boot = boot
        if reset:
            c.refused_resets += 1
            self._session_frame()  # at once: the refused controller learns why it gets no acknowledgement
        # News: the first refused frame of a session, and each controller's first refused RESET
        # (at most 64 of them); the rest are counted (PLANT_SESSION.Refused).
        first = c.refused - self._refused_at_open == 1
        if first or (reset and boot not in self._refused_boots and len(self._refused_boots) < 64):
            if reset:
                self._refused_boots.add(boot)
            sender = f"boot id low byte {boot:#04x}" if kind == "CMD" else f"controller {boot:#06x}"
            owner = "no session" if self.session_owner is None else f"session of {self.session_owner:#06x}"
            log.warning("plant node: %s from %s refused (%s); further refusals are counted", kind, sender, owner)

    def _control(self, raw: dict[str, Any], now: float) -> None:
        boot, command = int(raw["BootId"]), int(raw["Command"])
        owner = self._from_owner("CONTROL", raw)
        if command == CONTROL_RESET:
            if not (owner or self.session_open(now)):
                self._refuse("RESET", boot, reset=True)
                return
            self._owner_seen = self._last_controller = now
            if owner and not self._session_commanded and int(raw["Seed"]) == self.seed:
                self.counters.duplicate_resets += 1  # a resend crossing our acknowledgement
            else:
                self.counters.resets += 1
                self._reset_state(int(raw["Seed"]))
                self._sessions += 1
                self.session_owner, self.session_no = boot, (self._sessions - 1) % 15 + 1
                self._refused_at_open = self.counters.refused
                self._session_commanded = False
                self._session_frame()
            self.state = STATE_RUNNING
            self._status(boot, reset_ack=True)
            self._commands_again(now)
            return
        if not owner:
            self._refuse("CONTROL", boot)
            return
        self._owner_seen = self._last_controller = now
        if command == CONTROL_END:  # the owner closes its session: amplifiers idle, the node is free
            log.info("plant node: controller %#06x ended its session %d", boot, self.session_no)
            self.cmd_raw = self._idle_raw()
            self.session_owner, self.session_no = None, 0
            # a clean end: the amplifiers are idle and no command is due, so the command timeout
            # is disarmed (it latched every amplifier 0.2 s after every clean run) until the next one
            self._owner_seen = self._last_controller = self._last_command = None
            self._gaps.clear()
            self.state = STATE_READY
            self._session_frame()
            return
        self._commands_again(now)  # NONE (or a command this node does not know): alive, no action

    # --- the amplifier side ---------------------------------------------------------------------
    def amplifiers(self) -> AmplifierState:
        """The amplifiers now: which are on, which the watchdog or the command timeout latched off."""
        if isinstance(self.plant, AmplifierSide):
            enabled, cause = self.plant.amplifier_enabled(), self.plant.amplifier_watchdog_cause()
        else:
            enabled, cause = self.cmd_raw["AmpEnable"] != 0, np.zeros(self.n, dtype=np.int64)
        return AmplifierState(np.asarray(enabled, bool), np.asarray(cause, np.int64), self.command_timed_out)

    def check_command_timeout(self, now: float | None = None) -> bool:
        """Bring the command timeout into force when no CONTROL/SYNC came for ``command_timeout_s``
        (call while no frame is waiting: a queued SYNC is no silence). True when it did now."""
        expiry = self._command_expiry()
        now = self.clock() if now is None else now
        if expiry is None or self._last_command is None or now <= expiry:
            return False
        silence = now - self._last_command
        self.command_timed_out = True
        self.last_silence_s = silence
        self.counters.command_timeouts += 1
        latched = np.zeros(self.n, dtype=bool)
        if isinstance(self.plant, AmplifierSide):
            latched = np.asarray(self.plant.hold_amplifiers_off(WATCHDOG_COMMAND_TIMEOUT), bool)
        # A warning only when it cut power: a controller pausing with its amplifiers off is no event.
        log.log(logging.WARNING if latched.any() else logging.INFO,
                "plant node: command timeout: no CONTROL/SYNC for %.3f s (limit %g s); %d amplifier(s) latched off",
                silence, self.effective_command_timeout_s(), int(np.count_nonzero(latched)))
        self._note_trips()
        self.heartbeat(now, force=True)
        return True

    def effective_command_timeout_s(self) -> float | None:
        """The command timeout in force (s; None: off). ``"auto"`` follows the rig's period and the
        link's measured lateness: ``AUTO_TIMEOUT_PERIODS`` servo periods (0.2 s at 125 Hz), or
        ``AUTO_LATENESS_FACTOR`` × the longest of the last ``AUTO_GAP_WINDOW`` gaps between the
        controller's commands when that is longer (a loaded machine's late ticks must not trip it),
        never beyond ``AUTO_TIMEOUT_MAX_S``."""
        if self.command_timeout_s != AUTO:
            return None if self.command_timeout_s is None else float(self.command_timeout_s)
        lateness = max(self._gaps, default=0.0)
        return min(AUTO_TIMEOUT_MAX_S, max(AUTO_TIMEOUT_PERIODS * self.period_s, AUTO_LATENESS_FACTOR * lateness))

    def _command_expiry(self) -> float | None:
        """When the command timeout comes into force unless a CONTROL/SYNC arrives (None: not armed)."""
        timeout = self.effective_command_timeout_s()
        if timeout is None or self._last_command is None or self.command_timed_out:
            return None
        return self._last_command + timeout

    def _note_trips(self) -> bool:
        """Count amplifiers newly latched off (True when there are some)."""
        tripped = int(np.count_nonzero(self.amplifiers().tripped))
        new = tripped > self._trips_seen
        if new:
            self.counters.watchdog_trips += tripped - self._trips_seen
        self._trips_seen = tripped
        return new

    def _sync_plausible(self, period: float, delay: float) -> bool:
        """A SYNC asks for the rig's servo period (the node's ``period_s``) and a delay within
        it; anything else is dropped and counted (``bad_sync``), never stepped: one frame asking
        for a 10 s period would otherwise keep the node integrating for many seconds. The
        controller then sees no answer and safe-stops on its own stale-data check."""
        ok = (math.isfinite(period) and math.isclose(period, self.period_s, rel_tol=1e-6)
              and math.isfinite(delay) and 0.0 <= delay <= period)
        if not ok:
            self.counters.bad_sync += 1
            if self.counters.bad_sync == 1:  # the first one is news; the rest are counted
                log.warning("plant node: SYNC refused: period %r s, delay %r s (this rig: period %g s, "
                            "delay 0..period)", period, delay, self.period_s)
        return ok

    def _commands_again(self, now: float | None) -> None:
        if now is not None and self._last_command is not None:
            self._gaps.append(now - self._last_command)
        self._last_command = now
        if self.command_timed_out:
            self.command_timed_out = False
            if self.amplifiers().tripped.any():
                log.warning("plant node: commands again after the command timeout (latched amplifiers re-arm "
                            "when their enable rises)")

    # --- frames ---------------------------------------------------------------------------------
    def handle(self, m: can.Message) -> None:
        """Process one received frame (never raises on bad frames)."""
        if self.fault("dead") is not None:
            return
        f = self.codec.try_decode(m)
        if f is None:
            return
        if f.kind == "CONTROL":
            self._control(f.raw, self.clock())
            return
        if f.kind in ("CMD", "SYNC", "HEARTBEAT_CONTROLLER"):
            if not self._from_owner(f.kind, f.raw):
                if f.kind != "HEARTBEAT_CONTROLLER":  # another controller's heartbeat commands nothing
                    boot = f.raw["BootIdLow"] if f.kind == "CMD" else f.raw["BootId"]
                    self._refuse(f.kind, int(boot))
                return
            self._owner_seen = self._last_controller = self.clock()
            if f.kind != "HEARTBEAT_CONTROLLER":
                self._session_commanded = True
        if f.kind == "CMD":
            j = int(f.joint or 0)
            if j >= self.n:
                self.counters.dropped += 1
                return
            for k in self.cmd_raw:
                self.cmd_raw[k][j] = f.raw[k]
            self.cmd_seq[j] = f.raw["Seq"]
        elif f.kind == "SYNC":
            self._commands_again(self._last_controller)  # SYNC and CONTROL are the command stream
            level = int(f.raw["Watchdog"])
            self._watchdog_edge |= level != self._watchdog_rx
            self._watchdog_rx = level
            if not self.free_running:
                period, delay = float(f.raw["PeriodS"]), float(f.raw["DelayS"])
                if not self._sync_plausible(period, delay):
                    return
                self.step(int(f.raw["Tick"]), period, delay)
        elif f.kind == "HEARTBEAT_CONTROLLER":
            pass  # alive, but no command: it does not hold the command timeout off
        else:  # another plant's frames on our bus
            self.counters.dropped += 1

    def step(self, tick: int, period_s: float, delay_s: float) -> None:
        """Advance the plant one period with the held commands and publish the answer."""
        c = self.counters
        if self.last_tick is not None and tick != self.last_tick + 1:
            c.seq_jumps += 1
        self.last_tick = tick
        if not self.free_running:
            missing = int(np.count_nonzero(self.cmd_seq != (tick & 0xFF)))
            c.missing_cmd += missing
        raw = self.cmd_raw
        if self.free_running and self._controller_lost():
            raw = self._idle_raw()
        # One edge per step in which at least one arrived: in lockstep (one SYNC per step) that is
        # the received level itself; free-running, toggles that arrive two to a step still count.
        if self._watchdog_edge:
            self._watchdog_fed ^= 1
            self._watchdog_edge = False
        raw = {**raw, "Watchdog": np.asarray(self._watchdog_fed, dtype=np.int64)}
        cmd = self.codec.command_from_raw(raw, self.command_type)
        try:
            sensors = self.plant.step_period(cmd, period_s, delay_s)
        except Exception as e:  # the plant refused (e.g. a bad period): tell the controller
            c.step_errors += 1
            log.warning("plant node: step %d failed: %s: %s", tick, type(e).__name__, e)
            self._status(tick, step_error=True)
            return
        c.steps += 1
        for msg in self.codec.sensor_frames(self.codec.sensors_raw(sensors), tick, sensors.truth,
                                            totals=self.totals.add(sensors.encoder), boot_id=self.boot_id):
            self._send(msg)
        self._status(tick)
        if self._note_trips():  # the watchdog line stopped (free-running), or an enable into a dead pump
            log.warning("plant node: step %d: %s", tick, self.amplifiers().describe(self.names))
            self.heartbeat(force=True)

    def _controller_lost(self) -> bool:
        lost = self._last_controller is None or self.clock() - self._last_controller > self.controller_timeout_s
        if lost and self.state == STATE_RUNNING:
            self.counters.controller_lost += 1
            self.state = STATE_STOPPED
        elif not lost and self.state == STATE_STOPPED:
            self.state = STATE_RUNNING
        return lost

    # --- serving --------------------------------------------------------------------------------
    def serve(self, stop: threading.Event | None = None, duration_s: float | None = None) -> None:
        """Serve until ``stop`` is set or ``duration_s`` of wall time has passed."""
        t_end = None if duration_s is None else self.clock() + duration_s
        next_step = self.clock() + self.period_s
        free_tick = 0
        while not (stop is not None and stop.is_set()):
            now = self.clock()
            if t_end is not None and now >= t_end:
                return
            self.heartbeat(now)
            if self.free_running and now >= next_step and self.fault("dead") is None:
                self.step(free_tick, self.period_s, self.delay_s)
                free_tick += 1
                next_step += self.period_s
                if next_step < now:  # fell behind by more than a period: do not burst
                    next_step = now + self.period_s
                continue
            wait = self._next_hb - now
            if self.free_running:
                wait = min(wait, next_step - now)
            expiry = self._command_expiry()
            if expiry is not None:  # wake just past it: the timeout acts on time, not at the next poll
                wait = min(wait, expiry - now + 1e-3)
            if t_end is not None:
                wait = min(wait, t_end - now)
            m = self.ep.recv(max(0.0, min(wait, 0.05)))
            if m is not None:
                self.handle(m)
            else:  # nothing waiting: a silence is real (frames queued behind a stall are not one)
                self.check_command_timeout()

    def start_thread(self) -> tuple[threading.Thread, threading.Event]:
        """Serve in a daemon thread; set the returned event to stop it."""
        stop = threading.Event()
        t = threading.Thread(target=self.serve, args=(stop,), name="vmehil-plant-node", daemon=True)
        t.start()
        return t, stop

    def close(self) -> None:
        self.ep.close()


def exit_on_sigterm() -> None:
    """Turn SIGTERM into ``SystemExit`` so a terminated node still closes its bus and its log."""

    def _exit(signum: int, frame: Any) -> None:
        raise SystemExit(0)

    signal.signal(signal.SIGTERM, _exit)
