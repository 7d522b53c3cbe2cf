"""Driver for the 4-channel quadrature decoder board (register map: :mod:`hal.quadrature.quad_regs`).

Counts are read through the output latch (LATCH command, then ``OL_HI``/``OL_LO``), never from
the live counter, so a read cannot tear. The 24-bit count is unwrapped to an unbounded
integer by taking each read's difference modulo 2**24 into ``[-2**23, 2**23)``: the driver
must read each channel at least once per half range of travel (2**23 counts: 4194 motor
revolutions of a 500-line encoder in x4). Travel of more than a quarter range between reads
is cross-checked against the board's OVERFLOW/UNDERFLOW flags and a contradiction raises
:class:`TrackingLostError` rather than silently picking the wrong branch.

Units: counts in the channel's current mode (x1/x2/x4); ``counts_per_rev`` is given in **x4
counts per revolution** (encoder lines × 4) and scaled by the mode; positions in radians,
velocities in rad/s, ``dt`` in seconds.

Velocity: each tick (:meth:`QuadratureDriver.update` or :meth:`QuadratureDriver.velocity`)
takes the count difference ``Δ`` since the previous tick. When ``|Δ| >= low_speed_counts`` the
estimate is ``Δ/dt``. Below, it is the 1/T estimate ``n/(m·dt)``: ``n`` counts since the last
tick at which the count changed ``m`` ticks ago. While the count does not change the estimate
is bounded by one count per elapsed time, ``sign·min(|v|, 1/(m·dt))``, and reaches 0 after
``stop_ticks`` ticks without a count.

Errors are never hidden: ILLEGAL (A and B changed in one sample: counts were lost) is sticky
in the board and raises :class:`IllegalTransitionError` on every read until
:meth:`QuadratureDriver.clear_errors`; with ``errors="report"`` the flags are returned in
each :class:`ChannelReading` instead.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`QuadratureDriver.from_lanes` stacks B drivers
over a bus of lanes. Its :meth:`~QuadratureDriver.update` makes the scalar tick's cycles and
returns readings whose numbers (``raw``, ``counts``, ``position_rad``, velocities, the status
bits) are lane values; each lane's unwrapping and velocity estimator are its own. The tick's
cycles do not depend on the counts (the wrap flags are cleared on every read, set or not), so
every lane makes them; where a scalar driver would raise (tracking lost, a count jump, ILLEGAL
with ``errors="raise"``) those lanes are ejected (``lanes.eject``) and the others go on. Only
the per-tick operations run in lane mode (:meth:`~QuadratureDriver.update`,
:meth:`~QuadratureDriver.clear_illegal`); set-up and homing are done on the scalar drivers
before stacking.

Example::

    qd = QuadratureDriver(bus, 0x5000, counts_per_rev=2000.0)   # 500-line encoders, x4
    qd.arm_index(0)
    ...                                  # move slowly until qd.index_seen(0)
    qd.home_at_index(0)                  # position 0 rad at the index
    r = qd.update(0.008)                 # every servo tick: readings for all channels
    theta, omega = r[0].position_rad, r[0].velocity_rad_s
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from hal.errors import HalError
from hal.lanes import LaneSet, LaneValue, stack
from hal.quadrature.quad_regs import (
    BOARD_TYPE,
    CHANNELS,
    CMD_CLEAR,
    CMD_LATCH,
    CMD_PRESET,
    COUNTER_MASK,
    COUNTER_MODULUS,
    MODE_CODES,
    MODE_HOLD,
    QUAD_REGS,
    ST_ILLEGAL,
    ST_INDEX,
    ST_OVERFLOW,
    ST_UNDERFLOW,
    reg_name,
)
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BoardIdError
from hal.vme.window import BoardWindow

_HALF = COUNTER_MODULUS // 2
_QUARTER = COUNTER_MODULUS // 4
TWO_PI = 2.0 * math.pi


class QuadratureError(HalError):
    """Base class of quadrature decoder errors; ``channel`` names the channel."""

    def __init__(self, channel: int, message: str) -> None:
        self.channel = channel
        self.readings: dict[int, ChannelReading] = {}
        super().__init__(f"quadrature channel {channel}: {message}")


class IllegalTransitionError(QuadratureError):
    """A and B changed in one sample: the shaft outran the decoder (or noise); counts were lost."""


class TrackingLostError(QuadratureError):
    """The unwrapped count cannot be trusted: too much travel between reads (wrap flags disagree)."""


class CountJumpError(QuadratureError):
    """The count changed more in one tick than the configured plausibility limit."""


class IndexNotSeenError(QuadratureError):
    """Homing or an index check needs a captured index, and none was captured."""


class IndexMismatchError(QuadratureError):
    """The index was captured at a count that disagrees with the homed revolution grid."""

    def __init__(self, channel: int, error_counts: float) -> None:
        self.error_counts = error_counts
        super().__init__(
            channel,
            f"index captured {error_counts:+g} counts off the homed grid: counts were missed or "
            "gained (check encoder wiring, speed vs decoder sampling rate); re-home the axis",
        )


@dataclass(frozen=True)
class ChannelStatus:
    """The STATUS register of one channel, decoded."""

    index: bool
    illegal: bool
    overflow: bool
    underflow: bool
    a: bool
    b: bool
    raw: int

    @classmethod
    def decode(cls, raw: int) -> ChannelStatus:
        return cls(bool(raw & ST_INDEX), bool(raw & ST_ILLEGAL), bool(raw & ST_OVERFLOW),
                   bool(raw & ST_UNDERFLOW), bool(raw >> 8 & 1), bool(raw >> 9 & 1), raw)

    @classmethod
    def decode_lanes(cls, raw: LaneValue) -> ChannelStatus:
        """:meth:`decode` of a lane value: every field a lane value (bool arrays, ``raw`` as read)."""
        flags: Any = raw
        return cls(flags & ST_INDEX != 0, flags & ST_ILLEGAL != 0, flags & ST_OVERFLOW != 0,
                   flags & ST_UNDERFLOW != 0, flags >> 8 & 1 != 0, flags >> 9 & 1 != 0, raw)


@dataclass(frozen=True)
class ChannelReading:
    """One channel after a servo tick (SI units)."""

    channel: int
    raw: int  #: latched 24-bit counter value
    counts: int  #: unwrapped count (mode units)
    position_rad: float
    velocity_counts_s: float
    velocity_rad_s: float
    status: ChannelStatus


class _Track:
    def __init__(self, raw: int, mode: int) -> None:
        self.raw = raw
        self.counts = raw - COUNTER_MODULUS if raw >= _HALF else raw
        self.mode = mode
        self.zero = 0.0
        self.home_index: int | None = None
        # velocity estimator
        self.tick_counts: int | None = None
        self.change_counts = 0
        self.ticks_since_change = 0
        self.velocity = 0.0


class _LaneTrack:
    """:class:`_Track` of B lanes: every number a lane value (arrays of shape (B,), replaced and
    never changed in place, so a reading may keep them); ``home_index``/``tick_counts`` are
    ``None`` when they are in every lane."""

    raw: LaneValue
    counts: LaneValue
    mode: LaneValue
    zero: LaneValue
    home_index: LaneValue | None
    tick_counts: LaneValue | None
    change_counts: LaneValue
    ticks_since_change: LaneValue
    velocity: LaneValue

    def __init__(self, tracks: Sequence[_Track]) -> None:
        def lanes(values: list[Any], dtype: Any) -> np.ndarray:
            return np.array(values, dtype=dtype)

        def optional(values: list[int | None], what: str) -> np.ndarray | None:
            if all(v is None for v in values):
                return None
            if any(v is None for v in values):
                raise NotImplementedError(f"the lanes' decoder channels differ in {what} (set in some only)")
            return lanes(values, np.int64)

        self.raw = lanes([t.raw for t in tracks], np.int64)
        self.counts = lanes([t.counts for t in tracks], np.int64)
        self.mode = stack([t.mode for t in tracks])
        self.zero = lanes([t.zero for t in tracks], np.float64)
        self.home_index = optional([t.home_index for t in tracks], "their home")
        self.tick_counts = optional([t.tick_counts for t in tracks], "their velocity estimator's start")
        self.change_counts = lanes([t.change_counts for t in tracks], np.int64)
        self.ticks_since_change = lanes([t.ticks_since_change for t in tracks], np.int64)
        self.velocity = lanes([t.velocity for t in tracks], np.float64)


#: operations a lane-mode driver does not run (set-up, homing, diagnostics: done on the scalar
#: drivers before they are stacked)
_SCALAR_ONLY = ("probe", "read_count", "read_count_unlatched", "status", "clear_errors", "set_mode", "hold",
                "preset", "clear", "position_counts", "position_rad", "set_zero", "velocity", "arm_index",
                "index_seen", "home_at_index", "check_index", "counts_per_rev")


def _scalar_only(name: str, *args: Any, **kwargs: Any) -> Any:
    raise NotImplementedError(f"QuadratureDriver.{name} is not run in lanes (set-up and homing: scalar, "
                              "before stacking)")


class QuadratureDriver:
    """Quadrature decoder driver.

    Args:
        bus: the VME bus.
        base: board base address.
        space: address space (A16 short I/O normally).
        counts_per_rev: x4 counts per revolution (lines·4), one number or per channel.
        channels: channels in use (default all four).
        errors: ``"raise"`` (default) or ``"report"`` (flags only in the readings).
        max_counts_per_tick: plausibility limit on ``|Δ|`` per tick (``None``: off), raising
            :class:`CountJumpError`.
        low_speed_counts: below this many counts per tick the 1/T estimator is used.
        stop_ticks: ticks without a count after which the velocity estimate is 0.

    Construction latches and reads every channel in use (the unbounded count starts at the
    counter value sign-extended from 24 bits) and clears its OVERFLOW/UNDERFLOW flags; it
    does not change modes, presets or the index arm.
    """

    #: the board's channel count (hal.board_types: a board of role "quad" says how many it has)
    CHANNELS = CHANNELS
    #: lane mode (:meth:`from_lanes`): the lanes and each channel's tracking state of every lane
    _lanes: LaneSet
    _lane_track: dict[int, _LaneTrack]

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        counts_per_rev: dict[int, float] | float,
        channels: Iterable[int] = range(CHANNELS),
        errors: str = "raise",
        max_counts_per_tick: int | None = None,
        low_speed_counts: int = 4,
        stop_ticks: int = 125,
    ) -> None:
        self.win = BoardWindow(bus, base, QUAD_REGS, space)
        self.channels = tuple(sorted(set(channels)))
        for ch in self.channels:
            self._check_ch(ch)
        if isinstance(counts_per_rev, dict):
            missing = [ch for ch in self.channels if ch not in counts_per_rev]
            if missing:
                raise ValueError(f"counts_per_rev has no entry for channel(s) {missing}")
            cpr = {ch: float(counts_per_rev[ch]) for ch in self.channels}
        else:
            cpr = {ch: float(counts_per_rev) for ch in self.channels}
        for ch, v in cpr.items():
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"counts_per_rev for channel {ch} must be > 0 (got {v})")
        self.counts_per_rev_x4 = cpr
        if errors not in ("raise", "report"):
            raise ValueError(f"errors must be 'raise' or 'report' (got {errors!r})")
        self.errors = errors
        self.max_counts_per_tick = max_counts_per_tick
        self.low_speed_counts = max(1, int(low_speed_counts))
        self.stop_ticks = max(1, int(stop_ticks))
        self._latch_mask = sum(1 << ch for ch in self.channels)
        self._gcmd = "GCMD"
        self._gcmd_latch = QUAD_REGS["GCMD"].pack(latch=self._latch_mask)
        #: per channel its register names, built once (no f-strings per tick); by name, so the
        #: window's resolved cycle per name serves them (a Register object takes its general path)
        self._regs = {ch: {name: QUAD_REGS[reg_name(ch, name)].name for name in ("CMD", "STATUS", "OL_HI", "OL_LO")}
                      for ch in self.channels}
        #: decoded STATUS values, one immutable object per register value (no allocation per
        #: tick); the driver's own, so a new driver decodes afresh
        self._status_cache: dict[int, ChannelStatus] = {}
        self._track: dict[int, _Track] = {}
        for ch in self.channels:
            self.win.write(reg_name(ch, "CMD"), CMD_LATCH)
            self._track[ch] = _Track(self._read_ol(ch), self._read_mode(ch))
            self.win.write(reg_name(ch, "STATUS"), ST_OVERFLOW | ST_UNDERFLOW)

    # --- helpers -------------------------------------------------------------------------
    @staticmethod
    def _check_ch(ch: int) -> None:
        if not isinstance(ch, int) or not 0 <= ch < CHANNELS:
            raise ValueError(f"quadrature channel {ch!r} is not 0..{CHANNELS - 1}")

    def _t(self, ch: int) -> _Track:
        try:
            return self._track[ch]
        except KeyError:
            raise ValueError(f"quadrature channel {ch!r} is not in use (channels {self.channels})") from None

    def _read_mode(self, ch: int) -> int:
        code = self.win.read_field(reg_name(ch, "CTL"), "mode")
        return {v: k for k, v in MODE_CODES.items()}.get(code, 4)

    def _read_ol(self, ch: int) -> int:
        regs = self._regs[ch]  # every channel in use has its names (built before the first read)
        hi = self.win.read(regs["OL_HI"]) & 0xFF
        return hi << 16 | self.win.read(regs["OL_LO"])

    def counts_per_rev(self, ch: int) -> float:
        """Counts per revolution in the channel's current mode."""
        return self.counts_per_rev_x4[ch] * self._t(ch).mode / 4.0

    # --- raw access ----------------------------------------------------------------------
    def probe(self) -> int:
        """Read the ID register; return the board revision (ID[7:0]). Raises
        :class:`hal.vme.BoardIdError` when ID[15:8] is not the decoder's type 0x51 (wrong base
        address or board). Not part of construction, which makes only the cycles it documents."""
        ident = self.win.read("ID")
        if ident >> 8 != BOARD_TYPE:
            raise BoardIdError(
                f"no quadrature decoder at 0x{self.win.base:X}: ID reads 0x{ident:04X}, expected type "
                f"0x{BOARD_TYPE:02X} in bits 15:8; check the base address in the crate/rig file"
            )
        return ident & 0xFF

    def read_count(self, ch: int) -> int:
        """Latch and read the 24-bit counter (0..0xFFFFFF); cannot tear."""
        self._t(ch)
        self.win.write(reg_name(ch, "CMD"), CMD_LATCH)
        return self._read_ol(ch)

    def read_count_unlatched(self, ch: int) -> int:
        """Read the live counter high part then low part, without latching — may tear when
        counts arrive between the two cycles (diagnostics and demonstrations only)."""
        hi = self.win.read(reg_name(ch, "CNT_HI")) & 0xFF
        return hi << 16 | self.win.read(reg_name(ch, "CNT_LO"))

    def status(self, ch: int) -> ChannelStatus:
        self._check_ch(ch)
        return self._decode(self.win.read(reg_name(ch, "STATUS")))

    def clear_errors(self, ch: int) -> None:
        """Clear ILLEGAL, OVERFLOW and UNDERFLOW of a channel (after dealing with the cause)."""
        self._check_ch(ch)
        self.win.write(reg_name(ch, "STATUS"), ST_ILLEGAL | ST_OVERFLOW | ST_UNDERFLOW)

    def clear_illegal(self, ch: int) -> None:
        """Clear ILLEGAL alone (W1C), leaving OVERFLOW/UNDERFLOW to the unwrapping: a watchdog
        that counts the reads that found ILLEGAL set clears it after each."""
        self._check_ch(ch)
        self.win.write(reg_name(ch, "STATUS"), ST_ILLEGAL)

    def set_mode(self, ch: int, mode: int) -> None:
        """Counting mode 1, 2 or 4 (counts per quadrature cycle). The position in radians is
        kept continuous across the change (to the new resolution); :meth:`check_index` needs a
        new :meth:`home_at_index` afterwards."""
        if mode not in MODE_CODES:
            raise ValueError(f"quadrature mode {mode!r} is not 1, 2 or 4")
        t = self._t(ch)
        rad = self.position_rad(ch)
        self.win.modify(reg_name(ch, "CTL"), mode=MODE_CODES[mode])
        t.mode = mode
        t.zero = t.counts - rad * self.counts_per_rev(ch) / TWO_PI
        t.home_index = None  # the index grid is in old-mode counts: re-home before check_index()
        t.tick_counts = None

    def hold(self, ch: int) -> None:
        """Inhibit counting (CTL mode 3); :meth:`set_mode` resumes."""
        self._t(ch)
        self.win.modify(reg_name(ch, "CTL"), mode=MODE_HOLD)

    def preset(self, ch: int, value: int) -> None:
        """Load the counter with ``value`` (0..0xFFFFFF). The unwrapped count jumps with it and
        the zero moves along, so :meth:`position_rad` is unchanged (use :meth:`set_zero` to
        re-define the position)."""
        if not 0 <= value <= COUNTER_MASK:
            raise ValueError(f"preset {value} is not a 24-bit count")
        t = self._t(ch)
        self.win.write(reg_name(ch, "PRE_HI"), value >> 16)
        self.win.write(reg_name(ch, "PRE_LO"), value & 0xFFFF)
        self.win.write(reg_name(ch, "CMD"), CMD_PRESET | CMD_LATCH)  # latch the old, then preset
        self._resync(ch, t, self._read_ol(ch), value)

    def clear(self, ch: int) -> None:
        """Set the counter to 0 (like :meth:`preset` with 0; the position in radians is unchanged)."""
        t = self._t(ch)
        self.win.write(reg_name(ch, "CMD"), CMD_CLEAR | CMD_LATCH)
        self._resync(ch, t, self._read_ol(ch), 0)

    def _resync(self, ch: int, t: _Track, old_raw: int, new_raw: int) -> None:
        self._unwrap(ch, t, old_raw, 0)
        shift = ((new_raw - old_raw + _HALF) % COUNTER_MODULUS) - _HALF
        t.counts += shift
        t.zero += shift
        if t.home_index is not None:
            t.home_index += shift
        if t.tick_counts is not None:
            t.tick_counts += shift
        t.raw = new_raw
        self.win.write(reg_name(ch, "STATUS"), ST_OVERFLOW | ST_UNDERFLOW)

    # --- unwrapping ----------------------------------------------------------------------
    def _unwrap(self, ch: int, t: _Track, raw: int, status: int) -> int:
        d = ((raw - t.raw + _HALF) % COUNTER_MODULUS) - _HALF
        if abs(d) > _QUARTER:
            crossing = 1 if t.raw + d > COUNTER_MASK else (-1 if t.raw + d < 0 else 0)
            ovf, unf = bool(status & ST_OVERFLOW), bool(status & ST_UNDERFLOW)
            ok = (crossing == 1 and ovf) or (crossing == -1 and unf) or (crossing == 0 and ovf == unf)
            if not ok:
                t.counts += d  # keep tracking from here (best guess); the home is no longer valid
                t.raw = raw
                t.home_index = None
                raise TrackingLostError(
                    ch,
                    f"count moved {d:+d} (more than a quarter of the 24-bit range) since the last read and the "
                    f"wrap flags (overflow={ovf}, underflow={unf}) disagree: more than half a range of travel "
                    "between reads; read the channel more often and re-home",
                )
        t.counts += d
        t.raw = raw
        return d

    def _read_tracked(self, ch: int, *, latch: bool = True) -> tuple[int, ChannelStatus]:
        t = self._t(ch)
        regs = self._regs[ch]
        if latch:
            self.win.write(regs["CMD"], CMD_LATCH)
        st = self.win.read(regs["STATUS"])
        raw = self._read_ol(ch)
        wrap = st & (ST_OVERFLOW | ST_UNDERFLOW)
        if wrap:
            self.win.write(regs["STATUS"], wrap)
        self._unwrap(ch, t, raw, st)
        return raw, self._decode(st)

    def _decode(self, raw: int) -> ChannelStatus:
        st = self._status_cache.get(raw)
        if st is None:
            st = self._status_cache[raw] = ChannelStatus.decode(raw)  # at most 2**16 values
        return st

    def _raise_flags(self, ch: int, status: ChannelStatus) -> None:
        if status.illegal and self.errors == "raise":
            raise IllegalTransitionError(
                ch,
                "illegal transition (A and B changed in one decoder sample): counts were lost — the shaft "
                "outran the decoder's sampling rate or the signals are noisy; re-home, then clear_errors()",
            )

    def position_counts(self, ch: int) -> int:
        """Unwrapped, unbounded count (mode units). Call at least once per 2**23 counts of travel."""
        _, st = self._read_tracked(ch)
        self._raise_flags(ch, st)
        return self._t(ch).counts

    def position_rad(self, ch: int) -> float:
        """Position in radians relative to the home (zero) set by :meth:`home_at_index`/:meth:`set_zero`."""
        counts = self.position_counts(ch)
        return (counts - self._t(ch).zero) * TWO_PI / self.counts_per_rev(ch)

    def set_zero(self, ch: int, position_rad: float = 0.0) -> None:
        """Define the current position as ``position_rad``."""
        counts = self.position_counts(ch)
        self._t(ch).zero = counts - position_rad * self.counts_per_rev(ch) / TWO_PI

    # --- velocity ------------------------------------------------------------------------
    def _velocity_step(self, ch: int, t: _Track, dt: float) -> float:
        if not dt > 0:
            raise ValueError(f"dt must be > 0 s (got {dt})")
        if t.tick_counts is None:
            t.tick_counts = t.change_counts = t.counts
            t.ticks_since_change = 0
            t.velocity = 0.0
            return 0.0
        delta = t.counts - t.tick_counts
        t.tick_counts = t.counts
        t.ticks_since_change += 1
        if self.max_counts_per_tick is not None and abs(delta) > self.max_counts_per_tick:
            t.change_counts, t.ticks_since_change = t.counts, 0
            raise CountJumpError(
                ch,
                f"count changed by {delta:+d} in one tick (limit {self.max_counts_per_tick}): a counter jump or "
                "noise burst; check the encoder and re-home",
            )
        if delta != 0:
            if abs(delta) >= self.low_speed_counts:
                v = delta / dt
            else:
                v = (t.counts - t.change_counts) / (t.ticks_since_change * dt)
            t.change_counts, t.ticks_since_change = t.counts, 0
        elif t.ticks_since_change >= self.stop_ticks:
            v = 0.0
        else:
            bound = 1.0 / (t.ticks_since_change * dt)
            v = math.copysign(min(abs(t.velocity), bound), t.velocity) if t.velocity else 0.0
        t.velocity = v
        return v

    def velocity(self, ch: int, dt: float) -> float:
        """One estimator tick for ``ch`` (call once per servo period ``dt``); rad/s."""
        t = self._t(ch)
        _, st = self._read_tracked(ch)
        v = self._velocity_step(ch, t, dt)
        self._raise_flags(ch, st)
        return v * TWO_PI / self.counts_per_rev(ch)

    def update(self, dt: float) -> dict[int, ChannelReading]:
        """Latch all channels at one instant, read them, unwrap and estimate velocity.

        Call once per servo tick. Every channel is processed before an error is raised; the
        error carries all readings in ``err.readings``.
        """
        read, write = self.win.read, self.win.write
        write(self._gcmd, self._gcmd_latch)
        out: dict[int, ChannelReading] = {}
        first_error: QuadratureError | None = None
        raise_illegal = self.errors == "raise"
        for ch in self.channels:
            t = self._t(ch)
            try:
                # _read_tracked(ch, latch=False) and _read_ol inline: the same cycles in the same order
                regs = self._regs[ch]
                status = read(regs["STATUS"])
                hi = read(regs["OL_HI"]) & 0xFF
                raw = hi << 16 | read(regs["OL_LO"])
                # the wrap flags read are written back (W1C) on every read, 0x0000 when neither is
                # set (a 0 bit leaves its flag alone): the tick's cycles do not depend on the
                # counts, so instances batched in lanes make the same ones (a joint resting near
                # its start count crosses 0 every few dozen ticks, each instance at its own tick)
                write(regs["STATUS"], status & (ST_OVERFLOW | ST_UNDERFLOW))
                self._unwrap(ch, t, raw, status)
                st = self._decode(status)
                v = self._velocity_step(ch, t, dt)
                if st.illegal and raise_illegal:
                    self._raise_flags(ch, st)
            except QuadratureError as e:
                first_error = first_error or e
                st = self._decode(self.win.read(reg_name(ch, "STATUS")))
                raw, v = t.raw, t.velocity
            cpr = self.counts_per_rev_x4[ch] * t.mode / 4.0  # counts_per_rev(ch)
            out[ch] = ChannelReading(ch, raw, t.counts, (t.counts - t.zero) * TWO_PI / cpr, v, v * TWO_PI / cpr, st)
        if first_error is not None:
            first_error.readings = out
            raise first_error
        return out

    # --- lanes (batched lockstep) ---------------------------------------------------------
    @classmethod
    def from_lanes(cls, drivers: Sequence[QuadratureDriver], bus: VmeBus) -> QuadratureDriver:
        """One driver in lane mode for the B ``drivers`` (lane order: set up, same board address,
        channels and settings), on ``bus``, a bus of lanes (the stacked crate). Makes no cycle."""
        lanes = bus.lanes
        if lanes is None:
            raise ValueError("a lane-mode quadrature driver needs a bus of lanes (bus.lanes)")
        if len(drivers) != lanes.size:
            raise ValueError(f"{len(drivers)} drivers for {lanes.size} lanes")
        first = drivers[0]

        def settings(d: QuadratureDriver) -> tuple:
            return (type(d), d.win.base, d.win.am, d.channels, d.errors, d.max_counts_per_tick, d.low_speed_counts,
                    d.stop_ticks)

        if any(settings(d) != settings(first) for d in drivers):
            raise NotImplementedError(f"quadrature 0x{first.win.base:X}: the lanes' drivers are set up differently")
        drv = cls.__new__(cls)
        drv.win = BoardWindow(bus, first.win.base, QUAD_REGS, first.win.am)
        drv.channels = first.channels
        drv.counts_per_rev_x4 = {ch: stack([d.counts_per_rev_x4[ch] for d in drivers]) for ch in first.channels}
        drv.errors = first.errors
        drv.max_counts_per_tick = first.max_counts_per_tick
        drv.low_speed_counts = first.low_speed_counts
        drv.stop_ticks = first.stop_ticks
        drv._latch_mask = first._latch_mask
        drv._gcmd = first._gcmd
        drv._gcmd_latch = first._gcmd_latch
        drv._regs = first._regs
        drv._status_cache = {}
        drv._lanes = lanes
        drv._lane_track = {ch: _LaneTrack([d._track[ch] for d in drivers]) for ch in first.channels}
        drv._track = {}
        drv.update = drv._update_lanes  # type: ignore[method-assign]
        for name in _SCALAR_ONLY:
            setattr(drv, name, partial(_scalar_only, name))
        return drv

    def _update_lanes(self, dt: float) -> dict[int, ChannelReading]:
        """:meth:`update` on a bus of lanes: the same cycles; readings of lane values. A lane
        whose scalar driver would raise is ejected with the error's reason."""
        if not dt > 0:
            raise ValueError(f"dt must be > 0 s (got {dt})")
        win, lanes = self.win, self._lanes
        read, write = win.read, win.write
        write(self._gcmd, self._gcmd_latch)
        out: dict[int, ChannelReading] = {}
        where = f"quadrature 0x{win.base:X} channel"
        for ch in self.channels:
            t = self._lane_track[ch]
            regs = self._regs[ch]
            status = read(regs["STATUS"])
            hi = read(regs["OL_HI"]) & 0xFF
            raw = hi << 16 | read(regs["OL_LO"])
            write(regs["STATUS"], status & (ST_OVERFLOW | ST_UNDERFLOW))  # every read, as update()
            self._unwrap_lanes(ch, t, raw, status, lanes)
            st = ChannelStatus.decode_lanes(status)
            v = self._velocity_lanes(ch, t, dt, lanes)
            if self.errors == "raise":
                lanes.eject(st.illegal, f"{where} {ch}: IllegalTransitionError (ILLEGAL set)")
            cpr = self.counts_per_rev_x4[ch] * t.mode / 4.0
            counts = t.counts
            out[ch] = ChannelReading(ch, raw, counts, (counts - t.zero) * TWO_PI / cpr, v, v * TWO_PI / cpr, st)
        return out

    @staticmethod
    def _unwrap_lanes(ch: int, t: _LaneTrack, raw: LaneValue, status: LaneValue, lanes: LaneSet) -> None:
        """:meth:`_unwrap` per lane; a lane whose scalar driver raises TrackingLostError is ejected."""
        d = ((raw - t.raw + _HALF) % COUNTER_MODULUS) - _HALF
        far = np.abs(d) > _QUARTER
        if lanes.any(far):
            end = t.raw + d
            crossing = np.where(end > COUNTER_MASK, 1, np.where(end < 0, -1, 0))
            ovf, unf = status & ST_OVERFLOW != 0, status & ST_UNDERFLOW != 0
            ok = ((crossing == 1) & ovf) | ((crossing == -1) & unf) | ((crossing == 0) & (ovf == unf))
            lanes.eject(far & ~ok, f"quadrature channel {ch}: TrackingLostError (more than a quarter range "
                                   "between reads and the wrap flags disagree)")
        t.counts = t.counts + d
        t.raw = raw

    def _velocity_lanes(self, ch: int, t: _LaneTrack, dt: float, lanes: LaneSet) -> LaneValue:
        """:meth:`_velocity_step` per lane (the same float operations, so the same bits)."""
        counts = t.counts
        if t.tick_counts is None:  # the first tick in every lane (stacked before any update)
            t.tick_counts = t.change_counts = counts
            t.ticks_since_change = np.zeros(lanes.size, dtype=np.int64)
            t.velocity = np.zeros(lanes.size)
            return t.velocity
        delta = counts - t.tick_counts
        t.tick_counts = counts
        ticks = t.ticks_since_change + 1
        if self.max_counts_per_tick is not None:
            jump = np.abs(delta) > self.max_counts_per_tick
            if lanes.any(jump):
                lanes.eject(jump, f"quadrature channel {ch}: CountJumpError (limit {self.max_counts_per_tick})")
        moved = delta != 0
        velocity = t.velocity
        elapsed = ticks * dt  # > 0: ticks >= 1 in every lane, dead or alive
        changed = np.where(np.abs(delta) >= self.low_speed_counts, delta / dt, (counts - t.change_counts) / elapsed)
        bounded = np.copysign(np.minimum(np.abs(velocity), 1.0 / elapsed), velocity)
        still = np.where(ticks >= self.stop_ticks, 0.0, np.where(velocity != 0, bounded, 0.0))
        v = np.where(moved, changed, still)
        t.change_counts = np.where(moved, counts, t.change_counts)
        t.ticks_since_change = np.where(moved, 0, ticks)
        t.velocity = v
        return v

    # --- index and homing ----------------------------------------------------------------
    def arm_index(self, ch: int) -> None:
        """Clear STATUS.index and arm the index latch for the next index pulse."""
        self._t(ch)
        self.win.write(reg_name(ch, "STATUS"), ST_INDEX)
        self.win.modify(reg_name(ch, "CTL"), index_arm=1)

    def index_seen(self, ch: int) -> bool:
        """True once an armed index pulse has been captured."""
        return self.status(ch).index

    def _index_counts(self, ch: int) -> int:
        t = self._t(ch)
        if not self.index_seen(ch):
            raise IndexNotSeenError(ch, "no index captured; arm_index() and move through the index first")
        self.position_counts(ch)
        hi = self.win.read(reg_name(ch, "IDX_HI")) & 0xFF
        idx = hi << 16 | self.win.read(reg_name(ch, "IDX_LO"))
        return t.counts + ((idx - t.raw + _HALF) % COUNTER_MODULUS) - _HALF

    def home_at_index(self, ch: int, position_rad: float = 0.0) -> int:
        """Define the captured index as ``position_rad`` (0 by default); returns the unwrapped
        index count. Re-arms the index latch so :meth:`check_index` can verify later passes."""
        idx = self._index_counts(ch)
        t = self._t(ch)
        t.zero = idx - position_rad * self.counts_per_rev(ch) / TWO_PI
        t.home_index = idx
        self.arm_index(ch)
        return idx

    def check_index(self, ch: int, tolerance_counts: float = 0.5) -> float | None:
        """If the index was captured since the last check, compare it with the homed grid
        (a whole number of revolutions from the home index) and re-arm. Returns the error in
        counts (``None`` if no index was seen); raises :class:`IndexMismatchError` beyond
        ``tolerance_counts``."""
        t = self._t(ch)
        if t.home_index is None:
            raise IndexNotSeenError(ch, "the axis is not homed; call home_at_index() first")
        if not self.index_seen(ch):
            return None
        idx = self._index_counts(ch)
        cpr = self.counts_per_rev(ch)
        err = (idx - t.home_index + cpr / 2) % cpr - cpr / 2
        self.arm_index(ch)
        if abs(err) > tolerance_counts:
            raise IndexMismatchError(ch, err)
        return err
