"""Encode and decode the vmehil CAN message set (``vmehil.dbc``), and quantize like the wire does.

The DBC file is read **once** with cantools. Every scale, offset, bit length and value range used
here comes from it:

* :class:`CanCodec` quantizes a :class:`~emulators.plant.PlantCommand` /
  :class:`~emulators.plant.PlantSensors` to raw integers with numpy (round half to even, then
  clip to the signal's declared range), packs raw values into frames with cantools
  (``scaling=False``) and unpacks them again; raw → physical is ``raw * scale + offset`` in
  numpy on both paths.
* :class:`DbcExchangeCodec` is the harness's :class:`~emulators.plant_link.ExchangeCodec`: the
  same quantize → raw → physical round trip without the frames. The in-process link uses it,
  so an in-process run and a lockstep run over CAN see bit-identical values: the only extra step
  on CAN is cantools' bit packing, which is lossless for raw values inside the declared ranges.

Resolutions (see ``docs/can.md``): analog volts 2 µV (24-bit signed, ±16.78 V), PWM duty 1e-6,
encoder counts exact (24-bit signed per period), index offsets exact for up to two pulses per
period (first and last; more are spaced evenly between them), ground truth float64 (exact).
"""

from __future__ import annotations

import copy
import functools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import can
import cantools
import numpy as np
from cantools.database.can import Database as CanDatabase

from emulators.can.dbc import (
    DBC_PATH,
    ID_CMD,
    ID_CONTROL,
    ID_HEARTBEAT_CONTROLLER,
    ID_HEARTBEAT_PLANT,
    ID_SENS,
    ID_SESSION,
    ID_STATUS,
    ID_SYNC,
    ID_TRUTH,
    ID_UNIT_ANSWER,
    ID_UNIT_HEARTBEAT,
    ID_UNIT_POS,
    ID_UNIT_START,
    ID_UNIT_STOP,
    ID_UNIT_SYNC,
    ID_UNIT_TIMING,
    MAX_JOINTS,
)
from emulators.errors import EmulatorError
from emulators.signals import QuadratureEvents

#: truth keys carried by the TRUTH frames (float64, in this order)
TRUTH_SIGNALS = {"ThetaJoint": "theta_joint", "OmegaJoint": "omega_joint", "CurrentA": "current_a",
                 "FrictionNm": "friction_torque_nm"}

CMD_BITS = ("AmpEnable", "FaultReset", "PwmDirection", "Brake", "HoldingBrake")
#: the per-joint signals of CMD_Jxx (besides Seq); a command's raw dict also holds the rig-level
#: ``Watchdog`` line, which travels in SYNC
CMD_SIGNALS = ("AmpCommand", "PwmDuty", *CMD_BITS)


_SMALL = 64  #: arrays up to this length are quantized in plain Python (SignalSpec._quantize_small)


#: the unit bus's own frames (docs/melmalec.md) by identifier
_UNIT_KINDS = {ID_UNIT_STOP: "UNIT_STOP", ID_UNIT_START: "UNIT_START", ID_UNIT_SYNC: "UNIT_SYNC",
               ID_UNIT_POS: "UNIT_POS", ID_UNIT_TIMING: "UNIT_TIMING", ID_UNIT_ANSWER: "UNIT_ANSWER",
               ID_UNIT_HEARTBEAT: "UNIT_HEARTBEAT"}


class FrameError(EmulatorError, ValueError):
    """A frame that cannot be used: unknown identifier, wrong length, undecodable, or a value
    outside its declared range. Receivers count these and drop the frame."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason


@dataclass(frozen=True)
class SignalSpec:
    """One signal's wire format, read from the DBC."""

    name: str
    scale: float
    offset: float
    raw_min: float
    raw_max: float
    is_float: bool

    def quantize(self, values: Any) -> tuple[np.ndarray, int]:
        """Physical values → raw integers (round half to even, clipped to the declared range).
        Returns the raw array and how many values were clipped (NaN counts as clipped, → 0)."""
        v = np.asarray(values, dtype=float)
        if self.is_float:
            return v.copy(), 0
        if v.ndim == 1 and len(v) <= _SMALL:
            small = self._quantize_small(v.tolist())
            if small is not None:
                return small
        bad = ~np.isfinite(v)
        r = np.round((np.where(bad, self.offset, v) - self.offset) / self.scale)
        clipped = np.clip(r, self.raw_min, self.raw_max)
        n = int(np.count_nonzero(bad | (clipped != r)))
        return clipped.astype(np.int64), n

    def _quantize_small(self, values: list[float]) -> tuple[np.ndarray, int] | None:
        """:meth:`quantize` of a few finite values in plain Python floats (the in-process link
        quantizes ~10 arrays of one value per joint each tick; a dozen numpy calls on 7 values
        cost more than the arithmetic). The same IEEE operations in the same order — subtract,
        divide, round half to even (``round`` on a float is exact, as ``np.round``) — and the
        same clipping, so the result is bit-identical; ``None`` when a value (or its scaled
        value) is not finite: the array path then handles it."""
        got = self.quantize_list(values)
        if got is None:
            return None
        return np.array(got[0], dtype=np.int64), got[1]

    def quantize_list(self, values: list[float]) -> tuple[list[int], int] | None:
        """:meth:`_quantize_small` as a list of Python ints (the in-process exchange's fused path,
        :meth:`DbcExchangeCodec.sensors`); ``None`` for a non-finite value."""
        offset, scale, lo, hi = self.offset, self.scale, self.raw_min, self.raw_max
        raw: list[int] = []
        clipped = 0
        for x in values:
            y = (x - offset) / scale
            if y - y != 0.0:  # NaN or ±inf
                return None
            q = round(y)
            if q < lo:
                q, clipped = int(lo), clipped + 1
            elif q > hi:
                q, clipped = int(hi), clipped + 1
            raw.append(q)
        return raw, clipped

    def physical(self, raw: Any) -> np.ndarray:
        """Raw → physical: ``raw * scale + offset`` (float64)."""
        r = np.asarray(raw, dtype=float)
        if self.is_float:
            return r
        return r * self.scale + self.offset

    def in_range(self, raw: float) -> bool:
        if self.is_float:
            return True
        return self.raw_min <= raw <= self.raw_max


def _spec(sig) -> SignalSpec:
    scale, offset = float(sig.scale), float(sig.offset)
    if sig.is_float:
        return SignalSpec(sig.name, scale, offset, -np.inf, np.inf, True)
    lo_bits = -(2 ** (sig.length - 1)) if sig.is_signed else 0
    hi_bits = 2 ** (sig.length - 1) - 1 if sig.is_signed else 2**sig.length - 1
    lo = lo_bits if sig.minimum is None else max(lo_bits, round((sig.minimum - offset) / scale))
    hi = hi_bits if sig.maximum is None else min(hi_bits, round((sig.maximum - offset) / scale))
    return SignalSpec(sig.name, scale, offset, lo, hi, False)


@dataclass
class Frame:
    """A decoded frame: ``kind`` is the message name without the joint suffix (``CMD``, ``SENS``,
    ``TRUTH``, ``SYNC``, ``CONTROL``, ``PLANT_STATUS``, ``HEARTBEAT_CONTROLLER``,
    ``HEARTBEAT_PLANT``); ``joint`` is the joint index for per-joint frames; ``raw`` the raw
    signal values (floats for float64 signals)."""

    kind: str
    joint: int | None
    raw: dict[str, Any]
    timestamp: float = 0.0


@dataclass
class CodecCounters:
    """What the codec refused or clipped (totals since construction)."""

    clipped: int = 0
    unknown_id: int = 0
    wrong_length: int = 0
    undecodable: int = 0
    out_of_range: int = 0
    by_reason: dict[str, int] = field(default_factory=dict)


class CanCodec:
    """The message set of ``vmehil.dbc``: quantization, frame encoding and decoding.

    Args:
        dbc_path: the DBC file (default: the one shipped with the package).
    """

    def __init__(self, dbc_path: str | Path | None = None) -> None:
        self.path = Path(dbc_path) if dbc_path is not None else DBC_PATH
        # a DBC file loads as a CAN database (load_file's return type also admits a CDD diagnostics one)
        self.db = cast(CanDatabase, cantools.database.load_file(str(self.path)))
        by_id = {m.frame_id: m for m in self.db.messages}
        self.max_joints = sum(1 for m in self.db.messages if m.name.startswith("CMD_J"))
        if self.max_joints == 0:
            raise ValueError(f"{self.path}: no CMD_Jxx messages; is this the vmehil DBC?")
        self.specs: dict[str, dict[str, SignalSpec]] = {}
        self._by_id: dict[int, tuple[str, int | None, Any]] = {}
        for fid, msg in by_id.items():
            kind, joint = self._kind_of(fid)
            if kind is None:
                continue
            self._by_id[fid] = (kind, joint, msg)
            if kind not in self.specs:
                self.specs[kind] = {s.name: _spec(s) for s in msg.signals}
        self.counters = CodecCounters()

    @staticmethod
    def _kind_of(fid: int) -> tuple[str | None, int | None]:
        fixed = {ID_SYNC: "SYNC", ID_CONTROL: "CONTROL", ID_STATUS: "PLANT_STATUS",
                 ID_HEARTBEAT_CONTROLLER: "HEARTBEAT_CONTROLLER", ID_HEARTBEAT_PLANT: "HEARTBEAT_PLANT",
                 ID_SESSION: "PLANT_SESSION", **_UNIT_KINDS}
        if fid in fixed:
            return fixed[fid], None
        for base, kind in ((ID_CMD, "CMD"), (ID_SENS, "SENS"), (ID_TRUTH, "TRUTH")):
            if base <= fid < base + MAX_JOINTS:
                return kind, fid - base
        return None, None

    def message(self, kind: str, joint: int | None = None):
        """The cantools message of ``kind`` (and joint)."""
        base = {"CMD": ID_CMD, "SENS": ID_SENS, "TRUTH": ID_TRUTH}.get(kind)
        if base is not None:
            return self._by_id[base + int(joint or 0)][2]
        return self.db.get_message_by_name(kind)

    def check_joints(self, n: int) -> None:
        if not 0 < n <= self.max_joints:
            raise ValueError(f"{n} joints: the CAN message set carries 1..{self.max_joints} joints "
                             f"(regenerate {self.path.name} with a larger MAX_JOINTS)")

    def _q(self, kind: str, name: str, values: Any) -> np.ndarray:
        raw, n = self.specs[kind][name].quantize(values)
        self.counters.clipped += n
        return raw

    def _p(self, kind: str, name: str, raw: Any) -> np.ndarray:
        return self.specs[kind][name].physical(raw)

    # --- commands --------------------------------------------------------------------------------
    def command_raw(self, cmd) -> dict[str, np.ndarray]:
        """A plant command → raw signal arrays (one entry per joint; ``Watchdog``: the rig's one
        enable-watchdog line, a 0-d array)."""
        out = {
            "AmpCommand": self._q("CMD", "AmpCommand", cmd.amp_command_v),
            "PwmDuty": self._q("CMD", "PwmDuty", cmd.pwm_duty),
        }
        bits = (cmd.amp_enable, cmd.fault_reset, cmd.pwm_direction, cmd.brake, cmd.holding_brake)
        for name, arr in zip(CMD_BITS, bits, strict=True):
            out[name] = np.asarray(arr, dtype=bool).astype(np.int64)
        out["Watchdog"] = np.asarray(bool(cmd.watchdog_line), dtype=np.int64)
        return out

    def command_from_raw(self, raw: dict[str, np.ndarray], command_type: Callable[..., Any]):
        """Raw signal arrays → a command object built with ``command_type(**fields)``."""
        return command_type(
            amp_command_v=self._p("CMD", "AmpCommand", raw["AmpCommand"]),
            amp_enable=np.asarray(raw["AmpEnable"]) != 0,
            fault_reset=np.asarray(raw["FaultReset"]) != 0,
            pwm_duty=self._p("CMD", "PwmDuty", raw["PwmDuty"]),
            pwm_direction=np.asarray(raw["PwmDirection"]) != 0,
            brake=np.asarray(raw["Brake"]) != 0,
            holding_brake=np.asarray(raw["HoldingBrake"]) != 0,
            watchdog_line=bool(raw["Watchdog"]),
        )

    # --- sensors ---------------------------------------------------------------------------------
    def sensors_raw(self, s) -> dict[str, np.ndarray]:
        """Plant sensors → raw signal arrays (one entry per joint)."""
        n = len(s.pot_v)
        enc: Sequence[QuadratureEvents] = s.encoder
        counts = np.array([e.counts for e in enc], dtype=float)
        illegal = np.array([e.illegal for e in enc], dtype=float)
        phase = np.array([int(e.phase) % 4 for e in enc], dtype=np.int64)
        n_index = np.array([len(e.index_offsets) for e in enc], dtype=float)
        first = np.array([e.index_offsets[0] if e.index_offsets else 0 for e in enc], dtype=float)
        last = np.array([e.index_offsets[-1] if e.index_offsets else 0 for e in enc], dtype=float)
        switching = np.asarray(s.switching, dtype=bool)
        if switching.shape != (n,):
            switching = np.zeros(n, dtype=bool)
        return {
            "PotVoltage": self._q("SENS", "PotVoltage", s.pot_v),
            "TachVoltage": self._q("SENS", "TachVoltage", s.tach_v),
            "CurrentMonitor": self._q("SENS", "CurrentMonitor", s.imon_v),
            "EncoderCounts": self._q("SENS", "EncoderCounts", counts),
            "EncoderIllegal": self._q("SENS", "EncoderIllegal", illegal),
            "EncoderPhase": phase,
            "AmpFault": np.asarray(s.amp_fault, dtype=bool).astype(np.int64),
            "Switching": switching.astype(np.int64),
            "IndexCount": self._q("SENS", "IndexCount", n_index),
            "IndexFirst": self._q("SENS", "IndexFirst", first),
            "IndexLast": self._q("SENS", "IndexLast", last),
        }

    def sensors_from_raw(self, raw: dict[str, np.ndarray], sensors_type: Callable[..., Any],
                         truth: dict[str, np.ndarray] | None = None):
        """Raw signal arrays → a sensors object built with ``sensors_type(**fields)``."""
        events = [_events(*(int(x) for x in fields))
                  for fields in zip(*(np.asarray(raw[k]).tolist() for k in _EVENT_SIGNALS), strict=True)]
        return sensors_type(
            pot_v=self._p("SENS", "PotVoltage", raw["PotVoltage"]),
            tach_v=self._p("SENS", "TachVoltage", raw["TachVoltage"]),
            imon_v=self._p("SENS", "CurrentMonitor", raw["CurrentMonitor"]),
            amp_fault=np.asarray(raw["AmpFault"]) != 0,
            encoder=events,
            switching=np.asarray(raw["Switching"]) != 0,
            truth=dict(truth) if truth is not None else {},
        )

    # --- frames ----------------------------------------------------------------------------------
    def _frame(self, msg, values: dict[str, Any]) -> can.Message:
        data = msg.encode(values, scaling=False, padding=False, strict=False)
        return can.Message(arbitration_id=msg.frame_id, data=data, is_extended_id=False, is_fd=msg.is_fd,
                           bitrate_switch=msg.is_fd)

    def sensors_from_frames(self, sens: Mapping[int, Mapping[str, Any]], truth: Mapping[int, Mapping[str, Any]],
                            joints: Sequence[int], sensors_type: Callable[..., Any]):
        """The decoded SENS (and TRUTH) frames of ``joints`` (raw values by joint number; every
        joint's SENS present) → a sensors object in ``joints`` order; truth only when every
        joint's TRUTH frame came."""
        raw = {k: np.array([sens[j][k] for j in joints]) for k in sens[joints[0]] if k != "Seq"}
        truth_d = None
        if all(j in truth for j in joints):
            truth_d = {key: np.array([truth[j][sig] for j in joints]) for sig, key in TRUTH_SIGNALS.items()}
        return self.sensors_from_raw(raw, sensors_type, truth_d)

    def command_frames(self, raw: dict[str, np.ndarray], seq: int, boot_id: int = 0,
                       joints: Sequence[int] | None = None) -> list[can.Message]:
        """CMD frames of every joint (the ``Watchdog`` line goes in SYNC: :meth:`sync_frame`),
        marked with the low byte of the sender's boot id (the node takes its session owner's only).
        ``joints``: the frames' joint numbers for the entries of ``raw`` (default 0, 1, ...: a
        unit controller sends its joints' frames under their numbers in the whole rig)."""
        n = len(raw["AmpCommand"])
        ids = range(n) if joints is None else joints
        tail = {"Seq": seq & 0xFF, "BootIdLow": boot_id & 0xFF}
        # a signal missing from ``raw`` goes as 0 (a holding-brake line low: the brake holds)
        return [self._frame(self.message("CMD", j), {k: int(raw[k][i]) if k in raw else 0 for k in CMD_SIGNALS} | tail)
                for i, j in enumerate(ids)]

    def sync_frame(self, raw: dict[str, np.ndarray], tick: int, period_s: float, delay_s: float,
                   boot_id: int = 0) -> can.Message:
        """The SYNC of ``tick``, carrying the command's enable-watchdog line and the sender's boot id."""
        return self.frame("SYNC", Tick=tick & 0xFFFFFFFF, PeriodS=period_s, DelayS=delay_s, Seq=tick & 0xFF,
                          Watchdog=int(raw["Watchdog"]), BootId=boot_id & 0xFFFF)

    def sensor_frames(self, raw: dict[str, np.ndarray], seq: int,
                      truth: dict[str, np.ndarray] | None = None,
                      totals: Sequence[int] | np.ndarray | None = None, boot_id: int = 0) -> list[can.Message]:
        """SENS frames of every joint, then TRUTH frames when ``truth`` has the keys.
        ``totals``: each joint's running count (:class:`EncoderTotals`), else none is kept;
        ``boot_id``: the sender's (its low byte goes in every SENS frame)."""
        n = len(raw["PotVoltage"])
        out = [self._frame(self.message("SENS", j), {k: int(v[j]) for k, v in raw.items()} | {
            "Seq": seq & 0xFF, "EncoderTotal": 0 if totals is None else int(totals[j]) & _TOTAL_MASK,
            "HasTotal": int(totals is not None), "BootIdLow": boot_id & 0xFF}) for j in range(n)]
        if truth is not None and all(key in truth for key in TRUTH_SIGNALS.values()):
            cols = {sig: np.asarray(truth[key], dtype=float) for sig, key in TRUTH_SIGNALS.items()}
            out += [self._frame(self.message("TRUTH", j), {sig: float(c[j]) for sig, c in cols.items()})
                    for j in range(n)]
        return out

    def frame(self, kind: str, **values: Any) -> can.Message:
        """A non-joint frame (SYNC, CONTROL, PLANT_STATUS, HEARTBEAT_*) from raw values; missing
        signals are 0, integer values are clipped to their declared range."""
        msg = self.message(kind)
        specs = self.specs[kind]
        out: dict[str, Any] = {}
        for name, spec in specs.items():
            v = values.get(name, 0)
            out[name] = float(v) if spec.is_float else int(min(max(int(v), spec.raw_min), spec.raw_max))
        return self._frame(msg, out)

    def decode(self, m: can.Message) -> Frame:
        """A received frame → :class:`Frame`; raises :class:`FrameError` for anything unusable."""
        entry = self._by_id.get(m.arbitration_id) if not m.is_extended_id else None
        if entry is None or m.is_remote_frame or m.is_error_frame:
            raise FrameError("unknown_id", f"frame 0x{m.arbitration_id:X} is not in {self.path.name}")
        kind, joint, msg = entry
        data = bytes(m.data)
        if len(data) != msg.length:
            raise FrameError("wrong_length", f"{msg.name}: {len(data)} bytes, expected {msg.length}")
        try:
            raw = msg.decode(data, decode_choices=False, scaling=False, allow_truncated=False, allow_excess=False)
        except Exception as e:  # cantools raises several types for bad payloads
            raise FrameError("undecodable", f"{msg.name}: {type(e).__name__}: {e}") from None
        specs = self.specs[kind]
        for name, v in raw.items():
            if not specs[name].in_range(v):
                raise FrameError("out_of_range", f"{msg.name}.{name} raw {v} outside "
                                 f"[{specs[name].raw_min}, {specs[name].raw_max}]")
        return Frame(kind, joint, raw, float(m.timestamp or 0.0))

    def try_decode(self, m: can.Message) -> Frame | None:
        """:meth:`decode`, counting and dropping unusable frames (returns ``None``)."""
        try:
            return self.decode(m)
        except FrameError as e:
            c = self.counters
            setattr(c, e.reason, getattr(c, e.reason) + 1)
            c.by_reason[e.reason] = c.by_reason.get(e.reason, 0) + 1
            return None


#: the raw signals of one joint's QuadratureEvents, in the order of the cache key below
_EVENT_SIGNALS = ("EncoderCounts", "EncoderIllegal", "IndexCount", "IndexFirst", "IndexLast", "EncoderPhase")
#: decoded events per raw signal values: the in-process exchange decodes every joint every tick
_EVENTS: dict[tuple[int, ...], QuadratureEvents] = {}


def _events(counts: int, illegal: int, index_count: int, first: int, last: int, phase: int) -> QuadratureEvents:
    """The decoded :class:`QuadratureEvents` of one joint's raw signals, one object per distinct
    value (it is frozen, so equal events can be shared; the cache is bounded)."""
    key = (counts, illegal, index_count, first, last, phase)
    ev = _EVENTS.get(key)
    if ev is None:
        if len(_EVENTS) > 4096:
            _EVENTS.clear()
        ev = _EVENTS[key] = QuadratureEvents(counts=counts, illegal=illegal,
                                             index_offsets=index_offsets(index_count, first, last), phase=phase)
    return ev


def index_offsets(count: int, first: int, last: int) -> tuple[int, ...]:
    """Index pulse offsets from (count, first, last): exact for up to two pulses; more are spaced
    evenly from first to last (exact for the once-per-revolution index of a steadily turning
    encoder)."""
    if count <= 0:
        return ()
    if count == 1:
        return (first,)
    return tuple(first + round(k * (last - first) / (count - 1)) for k in range(count))


_TOTAL_MASK = 2**32 - 1


class EncoderTotals:
    """Each joint's net x4 count since the session's start, sent with every answer
    (``SENS.EncoderTotal``, mod 2³²), so that counts survive lost answers.

    A SENS frame's ``EncoderCounts`` are the period's own counts: an answer that never arrives
    (a free-running receiver reads the newest answers as they come; a datagram dropped by a
    receiver's full socket buffer or a lost frame on a real bus) would take its counts with it,
    and the incremental position would drift from the absolute pot for good. The sender keeps
    the running total (:meth:`add`, the counts before the frame's clipping); the receiver
    (:meth:`recover`) takes the total's advance since the previous answer it got as the counts:
    equal to the frame's counts when nothing was lost (lockstep always), else the lost answers'
    counts are in. Their index pulses and illegal transitions are not (:attr:`recovered` counts
    the answers that needed it)."""

    def __init__(self) -> None:
        self.total: np.ndarray | None = None  #: sender: per joint (int64, wrapped)
        self._last: dict[int, int] = {}  # receiver: joint → the last total heard
        self.recovered = 0  #: receiver: answers whose counts came from the total

    def add(self, encoder: Sequence[QuadratureEvents]) -> np.ndarray:
        """Sender: add an answer's counts; the totals to send with it."""
        counts = np.fromiter((e.counts for e in encoder), dtype=np.int64, count=len(encoder))
        self.total = counts & _TOTAL_MASK if self.total is None else (self.total + counts) & _TOTAL_MASK
        return self.total

    def reset(self) -> None:
        """A new session: the sender starts from 0, the receiver forgets the last totals."""
        self.total = None
        self._last.clear()

    def recover(self, sens: Mapping[int, Mapping[str, Any]], joints: Sequence[int],
                encoder: list[QuadratureEvents]) -> list[QuadratureEvents]:
        """Receiver: ``encoder`` (in ``joints`` order, decoded from ``sens``) with each joint's
        counts from its total's advance since the last answer (where both carried one)."""
        out = encoder
        lost = False
        for i, j in enumerate(joints):
            r = sens[j]
            if not int(r.get("HasTotal", 0)):
                self._last.pop(j, None)
                continue
            total = int(r["EncoderTotal"])
            prev = self._last.get(j)
            self._last[j] = total
            if prev is None:
                continue
            advance = ((total - prev + 2**31) & _TOTAL_MASK) - 2**31
            ev = encoder[i]
            if advance != ev.counts:
                if out is encoder:
                    out = list(encoder)
                out[i] = QuadratureEvents(counts=advance, illegal=ev.illegal, index_offsets=ev.index_offsets,
                                          phase=ev.phase)
                lost = True
        self.recovered += lost
        return out


class DbcExchangeCodec:
    """The harness codec: quantizes commands and sensors exactly as the CAN frames do.

    Duck-typed :class:`emulators.plant_link.ExchangeCodec` (``command(cmd)``, ``sensors(s)``);
    ground truth passes unchanged.
    """

    def __init__(self, codec: CanCodec | None = None) -> None:
        self.can = codec or shared_codec()
        sens = self.can.specs["SENS"]
        self._analog = tuple(sens[k] for k in ("PotVoltage", "TachVoltage", "CurrentMonitor"))
        self._counts = tuple(sens[k] for k in ("EncoderCounts", "EncoderIllegal", "IndexCount", "IndexFirst",
                                               "IndexLast"))
        #: the fused sensors path needs integer (scaled) signals; a float signal takes the general one
        self._fused = not any(spec.is_float for spec in (*self._analog, *self._counts))

    def command(self, cmd):
        return self.can.command_from_raw(self.can.command_raw(cmd), type(cmd))

    def sensors(self, s):
        out = self._sensors_fused(s) if self._fused else None
        if out is None:
            out = self.can.sensors_from_raw(self.can.sensors_raw(s), type(s), s.truth)
        return out

    # ---- lane mode (batched lockstep, issue #34): B plants' values side by side --------------
    def command_lanes(self, cmd: Any) -> Any:
        """:meth:`command` of a stacked command (:meth:`emulators.plant.PlantCommand.from_lanes`:
        per-joint arrays of B·n values, the watchdog line a bool or (B,)): the same quantization
        per element (one array operation over every lane), the watchdog line passed as it is."""
        line = cmd.watchdog_line
        cmd = copy.copy(cmd)
        cmd.watchdog_line = False
        out = self.can.command_from_raw(self.can.command_raw(cmd), type(cmd))
        out.watchdog_line = np.array(line, dtype=bool) if isinstance(line, np.ndarray) else bool(line)
        return out

    def sensors_lanes(self, s: Any) -> Any:
        """:meth:`sensors` of a stacked answer (:meth:`emulators.plant.PlantSensors.from_lanes`:
        per-joint arrays of B·n values, ``encoder`` one lane-mode :class:`QuadratureEvents` per
        joint): every value quantized as the scalar exchange quantizes it (the same IEEE
        operations per element, :meth:`SignalSpec.quantize`), the encoder's counts and index
        pulses decoded from their raw values as :func:`_events` does."""
        pot, tach, imon = (self._physical_lanes(spec, v) for spec, v in zip(self._analog, (s.pot_v, s.tach_v, s.imon_v),
                                                                          strict=True))
        enc: Sequence[QuadratureEvents] = s.encoder
        counts_spec, illegal_spec, k_spec, first_spec, last_spec = self._counts
        counts = self._raw_lanes(counts_spec, np.array([e.counts for e in enc], dtype=float))
        illegal = self._raw_lanes(illegal_spec, np.array([e.illegal for e in enc], dtype=float))
        phase = np.array([e.phase for e in enc], dtype=np.int64) % 4
        events = []
        for j, e in enumerate(enc):
            offsets: Any = e.index_offsets
            if any(offsets):
                lens = np.array([len(o) for o in offsets], dtype=float)
                first = np.array([o[0] if o else 0 for o in offsets], dtype=float)
                last = np.array([o[-1] if o else 0 for o in offsets], dtype=float)
                offsets = tuple(index_offsets(k, f, la) for k, f, la in zip(
                    self._raw_lanes(k_spec, lens).tolist(), self._raw_lanes(first_spec, first).tolist(),
                    self._raw_lanes(last_spec, last).tolist(), strict=True))
            events.append(QuadratureEvents(counts=counts[j], illegal=illegal[j], index_offsets=offsets,
                                           phase=phase[j]))
        n = np.size(s.pot_v)
        switching = np.asarray(s.switching, dtype=bool)
        if switching.shape != (n,):
            switching = np.zeros(n, dtype=bool)
        truth = s.truth
        return type(s)(
            pot_v=pot, tach_v=tach, imon_v=imon, amp_fault=np.array(s.amp_fault, dtype=bool), encoder=events,
            switching=switching.copy(), truth=dict(truth) if truth is not None else {},
        )

    def _raw_lanes(self, spec: SignalSpec, values: np.ndarray) -> np.ndarray:
        raw, clipped = spec.quantize(values)
        self.can.counters.clipped += clipped
        return raw

    def _physical_lanes(self, spec: SignalSpec, values: Any) -> np.ndarray:
        return spec.physical(self._raw_lanes(spec, values))

    def _sensors_fused(self, s: Any) -> Any:
        """:meth:`CanCodec.sensors_raw` then :meth:`CanCodec.sensors_from_raw` in plain Python
        numbers for a few joints: the same quantization (:meth:`SignalSpec.quantize_list`, as
        ``_quantize_small``), the same ``raw·scale + offset`` per value (two IEEE roundings, as the
        array expression), the same clip count, one array per field at the end; the events come
        from the same cache. ``None`` (nothing counted) where the general path must decide: more
        joints than the small path takes, a non-finite value, a shape it does not handle."""
        analog = [np.asarray(v, dtype=float) for v in (s.pot_v, s.tach_v, s.imon_v)]
        if analog[0].ndim != 1:
            return None
        n = len(analog[0])
        if n > _SMALL or any(a.shape != (n,) for a in analog):
            return None
        enc: Sequence[QuadratureEvents] = s.encoder
        if len(enc) != n:
            return None
        fields = ([float(e.counts) for e in enc], [float(e.illegal) for e in enc],
                  [float(len(e.index_offsets)) for e in enc],
                  [float(e.index_offsets[0] if e.index_offsets else 0) for e in enc],
                  [float(e.index_offsets[-1] if e.index_offsets else 0) for e in enc])
        clipped = 0
        physical = []
        for spec, a in zip(self._analog, analog, strict=True):
            got = spec.quantize_list(a.tolist())
            if got is None:
                return None
            clipped += got[1]
            scale, offset = spec.scale, spec.offset
            physical.append(np.array([float(q) * scale + offset for q in got[0]], dtype=float))
        raws = []
        for spec, values in zip(self._counts, fields, strict=True):
            got = spec.quantize_list(values)
            if got is None:
                return None
            clipped += got[1]
            raws.append(got[0])
        self.can.counters.clipped += clipped
        events = [_events(c, il, k, f, la, int(e.phase) % 4) for c, il, k, f, la, e in zip(*raws, enc, strict=True)]
        switching = np.asarray(s.switching, dtype=bool)
        if switching.shape != (n,):
            switching = np.zeros(n, dtype=bool)
        truth = s.truth
        return type(s)(
            pot_v=physical[0], tach_v=physical[1], imon_v=physical[2],
            amp_fault=np.asarray(s.amp_fault, dtype=bool).astype(np.int64) != 0,
            encoder=events, switching=switching.astype(np.int64) != 0,
            truth=dict(truth) if truth is not None else {},
        )


@functools.cache
def shared_codec() -> CanCodec:
    """One :class:`CanCodec` of the shipped DBC per process (the DBC is parsed once)."""
    return CanCodec()
