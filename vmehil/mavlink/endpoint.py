"""The MAVLink endpoint of a running servo loop: heartbeat, parameter protocol, telemetry, arming.

It never blocks the loop: :meth:`MavlinkEndpoint.service` reads what has arrived (non-blocking),
answers, and sends what is due; the runners call it after every tick (``runner.after_tick``), in
lockstep and in real time alike. Time for the heartbeat (1 Hz) and telemetry rates is the loop's
time (tick · period), so a lockstep run emits them at the simulated rates.

Changes (PARAM_SET, disarm) are handed to the loop with :meth:`servo.loop.ServoLoop.submit` and take
effect at the next tick boundary; the reply (PARAM_VALUE with the new value, or PARAM_ERROR plus
PARAM_VALUE with the old value and a STATUSTEXT saying why) is sent by the service after that tick.
Every change and refusal is logged with :meth:`servo.loop.ServoLoop.note` (source ``mavlink``).

Before the first tick (:meth:`wait_for_start`, ``--mavlink-wait``) nothing runs, so changes are
staged directly (they take effect at tick 0) and the run starts when a client arms
(``MAV_CMD_COMPONENT_ARM_DISARM`` 1). During a run, disarming safe-stops the loop.
"""

from __future__ import annotations

import math
import queue
import socket
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar

import numpy as np

import vmehil.mavlink  # noqa: F401  (MAVLINK20=1 before pymavlink)
from vmehil.errors import VmehilError
from vmehil.mavlink import params as P
from vmehil.mavlink.params import ParamRefused, ParamTable
from vmehil.mavlink.signing import UnsignedPolicy, install_verified_signature_check
from vmehil.mavlink.telemetry import array_messages, named_messages
from vmehil.option_groups.cli_types import is_loopback
from vmehil.writers.ascii_text import to_ascii


def _mavutil():
    from pymavlink import mavutil

    if mavutil.mavlink.WIRE_PROTOCOL_VERSION != "2.0":  # imported before MAVLINK20 was set
        mavutil.set_dialect(mavutil.current_dialect)
    return mavutil


class MavlinkError(VmehilError, ValueError):
    """A bad endpoint set-up (URL, remote bind, rate, key): the message says what to change."""


SCHEMES = ("udpin", "udpout", "udp", "tcpin", "tcp")


def check_url(url: str, allow_remote: bool = False) -> tuple[str, str, int]:
    """Validate ``scheme:host:port`` (udpin, udpout, udp = udpin, tcpin, tcp); ``host`` must be a
    loopback address unless ``allow_remote``. Returns (scheme, host, port)."""
    parts = url.split(":")
    if len(parts) != 3 or parts[0] not in SCHEMES:
        raise MavlinkError(f"--mavlink {url!r}: expected SCHEME:HOST:PORT with SCHEME one of {', '.join(SCHEMES)} "
                           "(e.g. udpin:127.0.0.1:14550)")
    scheme, host, port_s = parts
    try:
        port = int(port_s)
    except ValueError:
        raise MavlinkError(f"--mavlink {url!r}: port {port_s!r} is not a number") from None
    if not 0 <= port <= 65535:
        raise MavlinkError(f"--mavlink {url!r}: port {port} is out of range")
    if not allow_remote and not is_loopback(host):
        raise MavlinkError(f"--mavlink {url!r}: {host} is not a loopback address; the endpoint binds/sends to "
                           "127.0.0.1 (or ::1, localhost) only unless --mavlink-allow-remote is given")
    return scheme, host, port


@dataclass
class EndpointStats:
    """Counters (for tests and the run report)."""

    received: int = 0
    bad_data: int = 0
    handler_errors: int = 0
    param_values_sent: int = 0
    param_errors_sent: int = 0
    sets_applied: int = 0
    sets_refused: int = 0
    unsigned_refused: int = 0
    #: refusals by kind (what, why, who) → count; only the first of each kind is logged
    refusals: dict[tuple[Any, ...], int] = field(default_factory=dict)
    heartbeats_sent: int = 0
    telemetry_sent: int = 0
    errors: list[str] = field(default_factory=list)


class MavlinkEndpoint:
    """MAVLink 2 endpoint for ``loop`` (see the module docstring).

    ``url``: pymavlink connection string (``udpin:127.0.0.1:14550`` listens; ``udpout:…`` sends to
    a listening ground station). ``rate_hz``: telemetry samples per second of loop time (0 = off).
    ``key``: 32-byte signing key or None. ``allow_unsigned_read``: with a key, still answer unsigned
    PARAM_REQUEST_LIST/READ. ``delay_periods``/``min_margin``: stability check (see
    :class:`vmehil.mavlink.params.ParamTable`). ``telemetry``: ``"array"`` or ``"named"``.
    """

    MAX_RECV_PER_SERVICE = 64
    MAX_PARAM_SENDS_PER_SERVICE = 16

    def __init__(self, loop: Any, url: str, *, sysid: int = 1, compid: int = 1, rate_hz: float = 10.0,
                 key: bytes | None = None, allow_unsigned_read: bool = False, allow_remote: bool = False,
                 delay_periods: float = 0.0, min_margin: float = 0.0, telemetry: str = "array",
                 source: str = "mavlink") -> None:
        check_url(url, allow_remote)
        if not (math.isfinite(rate_hz) and 0.0 <= rate_hz <= 1.0 / loop.period_s):
            raise MavlinkError(f"--mavlink-rate {rate_hz}: expected 0 (off) .. {1.0 / loop.period_s:g} Hz "
                               "(the loop rate)")
        if telemetry not in ("array", "named"):
            raise MavlinkError(f"telemetry {telemetry!r}: expected 'array' or 'named'")
        if not (1 <= sysid <= 255 and 0 <= compid <= 255):
            raise MavlinkError(f"sysid {sysid} / compid {compid}: expected 1..255 / 0..255")
        mavutil = _mavutil()
        self.mavutil = mavutil
        self.ml = mavutil.mavlink
        self.loop = loop
        self.url = url
        self.sysid, self.compid = sysid, compid
        self.source = source
        self.telemetry = telemetry
        self.allow_unsigned_read = allow_unsigned_read
        self.table = ParamTable(loop, delay_periods=delay_periods, min_margin=min_margin)
        self.stats = EndpointStats()
        try:
            self.conn = mavutil.mavlink_connection(url, source_system=sysid, source_component=compid,
                                                   autoreconnect=False)
        except OSError as e:
            raise MavlinkError(f"--mavlink {url!r}: cannot open ({e})") from None
        self.key = key
        self.policy: UnsignedPolicy | None = None
        if key is not None:
            self.policy = UnsignedPolicy(self.ml)
            self.conn.setup_signing(key, sign_outgoing=True, allow_unsigned_callback=self.policy)
            install_verified_signature_check(self.conn.mav)
        ticks_per_s = 1.0 / loop.period_s
        self.hb_every = max(1, round(ticks_per_s))
        self.tm_every = 0 if rate_hz == 0 else max(1, round(ticks_per_s / rate_hz))
        self.rate_hz = 0.0 if rate_hz == 0 else ticks_per_s / self.tm_every
        self._outbox: deque[int] = deque()  # parameter indices to send (PARAM_VALUE)
        self._results: queue.SimpleQueue[Callable[[], None]] = queue.SimpleQueue()
        self._direct = False  # True while waiting before the first tick: apply changes at once
        self._armed_request = False
        self._fault_reported = False
        self._closed = False
        self._text_id = 0

    # --- the time base --------------------------------------------------------------------------------
    def after_tick(self, loop: Any) -> None:
        """``runner.after_tick`` callback: service the link; heartbeat/telemetry on loop time."""
        k = int(loop.tick_count)  # ticks done
        self.service()
        if self.loop.fault is not None and not self._fault_reported:
            self._fault_reported = True
            f = self.loop.fault
            self.send_heartbeat()
            self._statustext(self.ml.MAV_SEVERITY_CRITICAL,
                             f"servo loop stopped: {f.cause}" + (f" ({f.joint})" if f.joint else ""))
        try:
            if (k - 1) % self.hb_every == 0:
                self.send_heartbeat()
            if self.tm_every and (k - 1) % self.tm_every == 0:
                self.send_telemetry()
        except Exception as e:  # the link must never stop the loop
            self._error(f"streams: {type(e).__name__}: {e}")

    def wait_for_start(self, timeout_s: float, clock: Callable[[], float] = time.monotonic,
                       sleep: Callable[[float], None] = time.sleep) -> bool:
        """Before the first tick: serve the link (1 Hz wall-clock heartbeats, STANDBY) until a client
        arms, or ``timeout_s`` passes. Parameter changes are applied at once (staged for tick 0).
        Returns True when armed."""
        self._direct = True
        t_end = clock() + timeout_s
        next_hb = clock()
        try:
            while not self._armed_request:
                now = clock()
                if now >= t_end:
                    return False
                if now >= next_hb:
                    self.send_heartbeat(standby=True)
                    next_hb = now + 1.0
                if self.service() == 0:
                    sleep(0.005)
            self.send_heartbeat()
            return True
        finally:
            self._direct = False

    # --- servicing ----------------------------------------------------------------------------------
    def service(self) -> int:
        """Non-blocking: handle received messages (at most MAX_RECV_PER_SERVICE), send replies of
        changes applied since the last call and pending PARAM_VALUEs. Returns messages handled."""
        if self._closed:
            return 0
        while True:
            try:
                reply = self._results.get_nowait()
            except queue.Empty:
                break
            reply()
        handled = 0
        for _ in range(self.MAX_RECV_PER_SERVICE):
            try:
                msg = self.conn.recv_msg()
            except (OSError, ValueError, TypeError, IndexError, KeyError, self.ml.MAVError) as e:
                self.stats.bad_data += 1
                self._error(f"receive: {type(e).__name__}: {e}")
                continue
            if msg is None:
                break
            handled += 1
            self.stats.received += 1
            try:
                self.handle(msg)
            except Exception as e:  # one bad message must never stop the loop's link
                self.stats.handler_errors += 1
                self._error(f"handling {msg.get_type()}: {type(e).__name__}: {e}")
        self._flush_params()
        return handled

    def _error(self, text: str) -> None:
        if len(self.stats.errors) < 100:
            self.stats.errors.append(text)

    def handle(self, msg: Any) -> None:
        """Dispatch one received message."""
        mtype = msg.get_type()
        if mtype == "BAD_DATA":
            self.stats.bad_data += 1
            return
        handler = {
            "PARAM_REQUEST_LIST": self._on_request_list,
            "PARAM_REQUEST_READ": self._on_request_read,
            "PARAM_SET": self._on_param_set,
            "COMMAND_LONG": self._on_command_long,
            "MANUAL_CONTROL": self._on_manual_control,
        }.get(mtype)
        if handler is None:
            return
        if not self._for_me(msg):
            return
        handler(msg)

    def _for_me(self, msg: Any) -> bool:
        ts, tc = int(getattr(msg, "target_system", 0)), int(getattr(msg, "target_component", 0))
        return ts in (0, self.sysid) and tc in (0, self.compid)

    def _signed_ok(self, msg: Any, read: bool) -> bool:
        """With a key: only signed messages (and unsigned reads if allowed) are honoured."""
        if self.key is None or getattr(msg, "_signed", False):
            return True
        return read and self.allow_unsigned_read

    @staticmethod
    def _param_name(msg: Any) -> str:
        raw = msg.param_id
        if isinstance(raw, bytes):
            raw = raw.decode("ascii", errors="replace")
        return str(raw).split("\x00", 1)[0]

    @staticmethod
    def _origin(msg: Any) -> str:
        signed = "signed" if getattr(msg, "_signed", False) else "unsigned"
        return f"sys {msg.get_srcSystem()} comp {msg.get_srcComponent()}, {signed}"

    # --- parameter protocol -------------------------------------------------------------------------
    def _on_request_list(self, msg: Any) -> None:
        if not self._signed_ok(msg, read=True):
            self._refuse_unsigned("PARAM_REQUEST_LIST", "", -1, msg)
            return
        self._outbox.extend(range(len(self.table)))

    def _on_request_read(self, msg: Any) -> None:
        index = int(msg.param_index)
        name = self._param_name(msg)
        if not self._signed_ok(msg, read=True):
            self._refuse_unsigned("PARAM_REQUEST_READ", name, index, msg)
            return
        try:
            if index >= 0:
                self.table.at(index)
            else:
                index, _ = self.table.find(name)
        except ParamRefused as e:
            self._send_param_error(name if index < 0 else "", index, e.code, msg)
            self._statustext(self.ml.MAV_SEVERITY_WARNING, f"read {e.name}: {e.reason}")
            return
        self._send_param_value(index)

    def _on_param_set(self, msg: Any) -> None:
        name = self._param_name(msg)
        value = float(msg.param_value)
        origin = self._origin(msg)
        if not self._signed_ok(msg, read=False):
            self._refuse_unsigned("PARAM_SET", name, -1, msg)
            self._note_refusal(f"refused PARAM_SET {name} = {value:g} ({origin}): signing required",
                               ("unsigned", origin))
            return
        try:
            index, spec = self.table.find(name)
        except ParamRefused as e:
            self._refuse(e, -1, value, origin, msg)
            return
        try:
            command = self.table.apply_command(spec, value)
        except ParamRefused as e:
            self._refuse(e, index, value, origin, msg)
            return
        old = self.table.value(spec)

        def logged(loop: Any) -> float:
            # at the tick boundary: apply, then log with the time the change takes effect
            result = command(loop)
            unit = f" {spec.unit}" if spec.unit else ""
            loop.note(self.source, f"{spec.name} {old:g} -> {float(result):g}{unit} ({origin})")
            return result

        def done(result: Any, error: BaseException | None) -> None:
            # runs in the loop's thread at the tick boundary: hand the reply to the service
            self._results.put(lambda: self._set_done(index, spec, value, old, origin, result, error, msg))

        if self._direct:
            try:
                result = logged(self.loop)
            except Exception as e:
                done(None, e)
            else:
                done(result, None)
            self.service_results()
        else:
            self.loop.submit(logged, done)

    def service_results(self) -> None:
        while True:
            try:
                reply = self._results.get_nowait()
            except queue.Empty:
                return
            reply()

    def _set_done(self, index: int, spec: P.ParamSpec, value: float, old: float, origin: str, result: Any,
                  error: BaseException | None, msg: Any) -> None:
        if error is None:
            self.stats.sets_applied += 1
            self._send_param_value(index, float(result))
            return
        e = error if isinstance(error, ParamRefused) else ParamRefused(P.OUT_OF_RANGE, spec.name, str(error))
        self._refuse(e, index, value, origin, msg)

    def _refuse(self, e: ParamRefused, index: int, value: float, origin: str, msg: Any) -> None:
        self.stats.sets_refused += 1
        if self._note_refusal(f"refused {e.name} = {value:g} ({origin}): {e.reason}", (e.name, e.code, origin)):
            self._statustext(self.ml.MAV_SEVERITY_WARNING, f"{e.name}: {e.reason}")
        self._send_param_error(e.name if index < 0 else self.table.at(index).name, index, e.code, msg)
        if index >= 0:
            self._send_param_value(index)  # the old value, still in force

    def _note_refusal(self, text: str, kind: tuple[Any, ...]) -> bool:
        """Log a refusal the first time it happens for ``kind`` (what, why, who); count the
        rest (``stats.refusals``), so that a client hammering the endpoint cannot flood the
        run's log. Returns True for the first of its kind."""
        n = self.stats.refusals.get(kind, 0) + 1
        self.stats.refusals[kind] = n
        if n == 1:
            self.loop.note(self.source, text + " (repeats are counted, not logged)")
        return n == 1

    def _refuse_unsigned(self, what: str, name: str, index: int, msg: Any) -> None:
        self.stats.unsigned_refused += 1
        self._send_param_error(name, index, P.PERMISSION_DENIED, msg)
        if self.stats.refusals.get(("unsigned", self._origin(msg)), 0) == 0:
            self._statustext(self.ml.MAV_SEVERITY_WARNING, f"unsigned {what} refused: signing required")

    def _flush_params(self) -> None:
        for _ in range(self.MAX_PARAM_SENDS_PER_SERVICE):
            if not self._outbox:
                return
            self._send_param_value(self._outbox.popleft())

    def _send_param_value(self, index: int, value: float | None = None) -> None:
        spec = self.table.at(index)
        v = self.table.value(spec) if value is None else value
        self.conn.mav.param_value_send(spec.name.encode(), v, self.ml.MAV_PARAM_TYPE_REAL32, len(self.table), index)
        self.stats.param_values_sent += 1

    ERROR_CODES: ClassVar[dict[str, str]] = {
        P.DOES_NOT_EXIST: "MAV_PARAM_ERROR_DOES_NOT_EXIST", P.READ_ONLY: "MAV_PARAM_ERROR_READ_ONLY",
        P.OUT_OF_RANGE: "MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE", P.PERMISSION_DENIED: "MAV_PARAM_ERROR_PERMISSION_DENIED"}

    def _send_param_error(self, name: str, index: int, code: str, to: Any = None) -> None:
        """PARAM_ERROR addressed to the requester ``to`` (a received message); over UDP every
        client of the endpoint receives it."""
        err = getattr(self.ml, self.ERROR_CODES[code])
        ts, tc = (to.get_srcSystem(), to.get_srcComponent()) if to is not None else (0, 0)
        self.conn.mav.param_error_send(ts, tc, name[:16].encode("ascii", errors="replace"),
                                       max(-1, min(index, 32767)), err)
        self.stats.param_errors_sent += 1

    def _statustext(self, severity: int, text: str) -> None:
        """STATUSTEXT in ASCII (:func:`vmehil.writers.ascii_text.to_ascii`: ground stations show "?" for
        anything else); texts over 50 characters go out in chunks (MAVLink 2 ``id``/``chunk_seq``)."""
        raw = to_ascii(text).encode("ascii", errors="replace")
        if len(raw) <= 50:
            self.conn.mav.statustext_send(severity, raw)
            return
        self._text_id = self._text_id % 65535 + 1
        chunks = [raw[i:i + 50] for i in range(0, len(raw), 50)]
        for seq, chunk in enumerate(chunks):
            self.conn.mav.statustext_send(severity, chunk, self._text_id, seq)
        if len(raw) % 50 == 0:  # a chunk shorter than 50 (here empty) ends the text
            self.conn.mav.statustext_send(severity, b"", self._text_id, len(chunks))

    # --- commands --------------------------------------------------------------------------------------
    def _on_command_long(self, msg: Any) -> None:
        ml = self.ml
        if int(msg.command) != ml.MAV_CMD_COMPONENT_ARM_DISARM:
            self._ack(msg, ml.MAV_RESULT_UNSUPPORTED)
            return
        if not self._signed_ok(msg, read=False):
            self.stats.unsigned_refused += 1
            self._ack(msg, ml.MAV_RESULT_DENIED)
            self._statustext(ml.MAV_SEVERITY_WARNING, "unsigned arm/disarm refused: signing required")
            return
        arm = float(msg.param1) == 1.0
        origin = self._origin(msg)
        if self._direct:
            if arm:
                self._armed_request = True
                self.loop.note(self.source, f"armed: run starts ({origin})")
                self._ack(msg, ml.MAV_RESULT_ACCEPTED)
            else:
                self._ack(msg, ml.MAV_RESULT_ACCEPTED)
            return
        if arm:
            ok = self.loop.enabled and self.loop.fault is None
            self._ack(msg, ml.MAV_RESULT_ACCEPTED if ok else ml.MAV_RESULT_DENIED)
            return

        def stop(loop: Any) -> None:
            loop.safe_stop("operator_stop", f"disarmed over MAVLink ({origin})")

        def done(result: Any, error: BaseException | None) -> None:
            self._results.put(lambda: self._ack(msg, ml.MAV_RESULT_ACCEPTED if error is None else ml.MAV_RESULT_FAILED))

        self.loop.note(self.source, f"disarm requested ({origin})")
        self.loop.submit(stop, done)

    def _on_manual_control(self, msg: Any) -> None:
        """Jog (vmehil.mavlink.manual_control): each axis one joint's speed; each message renews
        the 0.5 s deadman. With a key only signed messages move the arm."""
        from vmehil.mavlink.manual_control import axis_speeds, jog_command

        if int(getattr(msg, "target", 0)) not in (0, self.sysid):
            return
        if not self._signed_ok(msg, read=False):
            self.stats.unsigned_refused += 1
            if self._note_refusal(f"refused MANUAL_CONTROL ({self._origin(msg)}): signing required",
                                  ("manual_control", "unsigned", self._origin(msg))):
                self._statustext(self.ml.MAV_SEVERITY_WARNING, "unsigned MANUAL_CONTROL refused: signing required")
            return
        plan = self.loop.plan_context or self.loop.sequencer.ctx
        speeds = axis_speeds(msg, np.asarray(plan.limits.v_max, float))
        if not speeds:
            return
        origin = self._origin(msg)

        def done(result: Any, error: BaseException | None) -> None:
            if error is not None:
                self._results.put(lambda: self._refuse_jog(str(error), origin))

        self.loop.submit(jog_command(speeds), done)

    def _refuse_jog(self, text: str, origin: str) -> None:
        """A jog the loop refused: logged and told to the ground station once per kind."""
        if self._note_refusal(f"{text} ({origin})", ("manual_control", text, origin)):
            self._statustext(self.ml.MAV_SEVERITY_WARNING, text)

    def _ack(self, msg: Any, result: int) -> None:
        self.conn.mav.command_ack_send(int(msg.command), result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent())

    # --- outgoing streams -------------------------------------------------------------------------------
    def system_status(self, standby: bool = False) -> int:
        """MAV_STATE for the heartbeat: STANDBY (waiting / not enabled), ACTIVE (running),
        EMERGENCY (stopped on a fault: amplifiers off), POWEROFF (closing)."""
        ml = self.ml
        if self._closed:
            return ml.MAV_STATE_POWEROFF
        if self.loop.fault is not None:
            return ml.MAV_STATE_EMERGENCY
        if standby or not self.loop.enabled:
            return ml.MAV_STATE_STANDBY
        return ml.MAV_STATE_ACTIVE

    def send_heartbeat(self, standby: bool = False) -> None:
        ml = self.ml
        status = self.system_status(standby)
        base = ml.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if status == ml.MAV_STATE_ACTIVE:
            base |= ml.MAV_MODE_FLAG_SAFETY_ARMED
        self.conn.mav.heartbeat_send(ml.MAV_TYPE_SERVO, ml.MAV_AUTOPILOT_GENERIC, base, 0, status)
        self.stats.heartbeats_sent += 1

    def send_telemetry(self) -> None:
        make = array_messages if self.telemetry == "array" else named_messages
        for m in make(self.conn.mav, self.loop):
            self.conn.mav.send(m)
            self.stats.telemetry_sent += 1

    def close(self) -> None:
        """Send a last POWEROFF heartbeat and close the link."""
        if self._closed:
            return
        try:
            self.service_results()
            self._closed = True
            self.send_heartbeat()
        except OSError:
            pass
        finally:
            self._closed = True
            try:
                self.conn.close()
            except OSError:
                pass


def free_udp_port(host: str = "127.0.0.1") -> int:
    """A UDP port free on ``host`` now (for tests and examples)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])
