"""Emulated 4-channel quadrature decoder board, written from its spec, docs/boards/quadrature.md.

A second reading of the board, independent of the driver: its register map, bit masks, ID and
counting rules are its own literals taken from the doc's tables (nothing from ``hal.quadrature``),
so a wrong offset, bit or width in the driver shows as a disagreement, not as a shared mistake.

Input: each channel is wired to a quadrature net; the harness publishes one
:class:`emulators.signals.QuadratureEvents` per interval (``Signals.publish_quadrature``),
made on the plant side at this board's input sampling rate (``sample_hz``) — by
:func:`emulators.plant.encoder.encoder_events` in the plant, by
:func:`emulators.encoder_edges.quadrature_events` for an encoder on its own. The board applies
the interval's counts when the events arrive.

Counting: the board keeps an x4 accumulator per channel (valid x4 transitions only) and the
24-bit counter advances by ``floor(acc/k)`` steps with ``k`` = 4 (x1), 2 (x2) or 1 (x4): x1
and x2 are a ÷4 / ÷2 prescaler on the x4 state machine, so counts change at fixed states and
never hunt. A mode change keeps the counter value and the prescaler residue. The counter
wraps modulo 2**24 setting OVERFLOW (carry) or UNDERFLOW (borrow). CLEAR/PRESET set the
counter and keep the residue. Illegal samples set ILLEGAL and count nothing.

Index: while CTL.index_arm is set, the first index pulse of an interval latches
``counter(start of interval) + steps(offset)`` into IDX, sets STATUS.index and disarms.

Misbehaviour kept on purpose: ``CNT_HI``/``CNT_LO`` read the live counter, so a multi-cycle
read tears when counts arrive between the cycles (e.g. 0x00FFFF → 0x010000 read high-first
gives 0x000000). Use the LATCH command and the output latch.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`QuadratureBoard.from_lanes` stacks B boards
into one whose counters, accumulators, latches, flags and A/B phases are int64 arrays of shape
(B,) (lane b's value at index b) and whose CTL/PRE registers are lane values; it takes the
lane-mode :class:`~emulators.signals.QuadratureEvents` (``emulators.plant.lanes.lane_events``) and
applies each lane's events by the same rules, so every lane's registers equal its scalar
board's. Injected faults are per instance: a lane-mode board has none (they run scalar).

Faults (one channel each, ``channel=n``):

- ``glitch(channel, counts=0, illegal=1, intervals=1)``: noise edges — each of the next
  ``intervals`` intervals gets ``counts`` extra x4 counts and ``illegal`` illegal samples.
- ``missed_counts(channel, counts=N)``: the next ``N`` incoming counts are dropped (at the
  start of each interval, index offsets shift accordingly).
- ``counter_jump(channel, counts=N)``: the live counter jumps by ``N`` steps when injected
  (a hit on the counter chip); wraps set OVERFLOW/UNDERFLOW.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any, ClassVar

import numpy as np

from emulators.board import Backplane, Board, RegisterBoard
from emulators.signals import QuadratureEvents
from hal.lanes import LaneValue
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the board as docs/boards/quadrature.md states it -----------------------------------
CHANNELS = 4
_WINDOW = 0xA0  #: bytes decoded from the base
_ID = 0x5101  #: type 0x51 ("Q") in [15:8], revision 0x01 in [7:0]
_MODULUS = 0x1000000  #: the counters wrap modulo 2**24
_TOP = 0xFFFFFF
# CTL
_ARM = 0x0010  #: [4] index_arm
_MODE = 0x0003  #: [1:0] mode
_CTL_BITS = _ARM | _MODE  #: the bits CTL keeps (others are ignored and read 0)
_HOLD = 3
_PRESCALE = (4, 2, 1)  #: x4 counts per counter step for mode codes 0 (x1), 1 (x2), 2 (x4)
_CTL_RESET = 0x0002  #: x4, index disarmed
# CMD (strobes, run in this order)
_LATCH, _CLEAR, _PRESET = 0x1, 0x2, 0x4
# STATUS
_INDEX, _ILLEGAL, _OVERFLOW, _UNDERFLOW = 0x1, 0x2, 0x4, 0x8
_FLAGS = 0x000F  #: the write-1-to-clear flags; [9:8] are the A/B levels (read-only)
_A_HIGH = (False, True, True, False)  #: A level per Gray state 0..3 (00, A, AB, B)
_B_HIGH = (False, False, True, True)

_D8 = (Width.D8,)
# lane mode: the same rules as lookup tables indexed by a lane array
_AB_BITS = np.array([_A_HIGH[p] << 8 | _B_HIGH[p] << 9 for p in range(4)], dtype=np.int64)  #: STATUS [9:8] per phase
_PRESCALE_BY_CODE = np.array([*_PRESCALE, 1], dtype=np.int64)  #: k per CTL.mode code (hold: any k, steps zeroed)


def _block(n: int) -> int:
    """Offset of channel ``n``'s register block (0x20, 0x40, 0x60, 0x80)."""
    return 0x20 + 0x20 * n


def _name(n: int, reg: str) -> str:
    return f"CH{n}_{reg}"


def _data(n: int, reg: str, off: int, access: Access, hi: str | None) -> Register:
    """One half of a 24-bit value: ``hi`` names the high half's 8-bit field (the low half has none)."""
    fields = (Field("value", 0, 8, hi),) if hi else ()
    return Register(_name(n, reg), _block(n) + off, Width.D16, access, fields=fields, also=_D8)


def _channel_registers(n: int) -> tuple[Register, ...]:
    ro, rw = Access.RO, Access.RW
    return (
        Register(_name(n, "CTL"), _block(n) + 0x00, Width.D16, rw, reset=_CTL_RESET, also=_D8,
                 fields=(Field("mode", 0, 2), Field("index_arm", 4, 1))),
        Register(_name(n, "CMD"), _block(n) + 0x02, Width.D16, Access.WO, also=_D8,
                 fields=(Field("latch", 0), Field("clear", 1), Field("preset", 2))),
        Register(_name(n, "STATUS"), _block(n) + 0x04, Width.D16, Access.W1C, also=_D8,
                 fields=(Field("index", 0), Field("illegal", 1), Field("overflow", 2), Field("underflow", 3),
                         Field("a", 8), Field("b", 9))),
        _data(n, "OL_HI", 0x08, ro, "output latch [23:16]"),
        _data(n, "OL_LO", 0x0A, ro, None),
        _data(n, "CNT_HI", 0x0C, ro, "live counter [23:16]"),
        _data(n, "CNT_LO", 0x0E, ro, None),
        _data(n, "IDX_HI", 0x10, ro, "index latch [23:16]"),
        _data(n, "IDX_LO", 0x12, ro, None),
        _data(n, "PRE_HI", 0x14, rw, "preset [23:16]"),
        _data(n, "PRE_LO", 0x16, rw, None),
    )


#: The emulator's own declaration of the board (checked against the doc by tests, not against
#: the driver's map).
BOARD_MAP = RegisterMap(
    "quad",
    _WINDOW,
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO, reset=_ID, also=_D8,
                 fields=(Field("rev", 0, 8), Field("type", 8, 8))),
        Register("GCMD", 0x02, Width.D16, Access.WO, also=_D8, fields=(Field("latch", 0, 4),)),
        *(r for n in range(CHANNELS) for r in _channel_registers(n)),
    ),
)

DEFAULT_SAMPLE_HZ = 1_000_000.0  #: decoder input sampling rate (HCTL-2016-like filter on a 4 MHz clock)


@dataclass
class _Channel:
    """One counter chip. CTL and PRE live in the board's ``regs`` (plain read/write storage,
    so a D8 write merges with the other byte's current value)."""

    counter: int = 0
    acc: int = 0  #: x4 counts since reset (the prescaler's input)
    ol: int = 0
    idx: int = 0
    status: int = 0  #: the W1C flags [3:0]
    phase: int = 0  #: last sampled Gray state 0..3
    glitch_left: int = 0
    missed_left: int = 0
    stats: dict[str, int] = field(default_factory=lambda: {"counts": 0, "illegal": 0, "index": 0, "intervals": 0})


class _LaneChannel:
    """One counter chip of B boards (lane mode): each field of :class:`_Channel` as an int64
    array of shape (B,). Fields are replaced, never changed in place (a latch shares the
    counter's array)."""

    __slots__ = ("acc", "counter", "idx", "ol", "phase", "stats", "status")

    def __init__(self, chans: Sequence[_Channel]) -> None:
        def lanes(values: Any) -> np.ndarray:
            return np.array(list(values), dtype=np.int64)

        self.counter = lanes(c.counter for c in chans)
        self.acc = lanes(c.acc for c in chans)
        self.ol = lanes(c.ol for c in chans)
        self.idx = lanes(c.idx for c in chans)
        self.status = lanes(c.status for c in chans)
        self.phase = lanes(c.phase for c in chans)
        self.stats = {k: lanes(c.stats[k] for c in chans) for k in chans[0].stats}


def _counter_steps_lanes(mode: LaneValue, acc_from: LaneValue, acc_to: LaneValue) -> LaneValue:
    """:meth:`QuadratureBoard._counter_steps` per lane (numpy ``//`` floors, as Python's)."""
    k = _PRESCALE_BY_CODE[mode]
    return np.where(mode == _HOLD, 0, acc_to // k - acc_from // k)


class QuadratureBoard(RegisterBoard):
    """Four 24-bit up/down counters fed by quadrature event summaries.

    Args:
        name: board name in the crate.
        nets: channel → quadrature net name (unwired channels never count).
        sample_hz: the input sampling rate the plant side must use for this board's encoders.
    """

    TYPE = "quad"
    REGMAP = BOARD_MAP
    FAULTS: ClassVar[dict[str, str]] = {
        "glitch": "channel, counts=0, illegal=1, intervals=1: noise edges in the next intervals",
        "missed_counts": "channel, counts=N: the next N incoming counts are lost",
        "counter_jump": "channel, counts=N: the counter jumps by N steps once",
    }

    def __init__(self, name: str, nets: dict[int, str] | None = None, sample_hz: float = DEFAULT_SAMPLE_HZ) -> None:
        self.nets = {int(ch): str(n) for ch, n in (nets or {}).items()}
        for ch in self.nets:
            if not 0 <= ch < CHANNELS:
                raise ValueError(f"{name}: channel {ch} is not 0..{CHANNELS - 1}")
        if not sample_hz > 0:
            raise ValueError(f"{name}: sample_hz must be > 0")
        self.sample_hz = float(sample_hz)
        self.ch = [_Channel() for _ in range(CHANNELS)]
        self._ctl = tuple(_name(c, "CTL") for c in range(CHANNELS))  # regs keys, built once
        self._pre = tuple((_name(c, "PRE_HI"), _name(c, "PRE_LO")) for c in range(CHANNELS))
        for c in range(CHANNELS):
            for reg, attr in (("OL", "ol"), ("CNT", "counter"), ("IDX", "idx")):
                setattr(self, f"read_{_name(c, reg + '_HI')}", partial(self._high, c, attr))
                setattr(self, f"read_{_name(c, reg + '_LO')}", partial(self._low, c, attr))
            setattr(self, f"write_{_name(c, 'PRE_HI')}", partial(self._store, _name(c, "PRE_HI"), 0x00FF))
            setattr(self, f"write_{_name(c, 'CTL')}", partial(self._store, _name(c, "CTL"), _CTL_BITS))
            setattr(self, f"write_{_name(c, 'CMD')}", partial(self._command, c))
            setattr(self, f"read_{_name(c, 'STATUS')}", partial(self._read_status, c))
            setattr(self, f"write_{_name(c, 'STATUS')}", partial(self._clear_flags, c))
        super().__init__(name)

    def attach(self, crate) -> None:
        super().attach(crate)
        for c, net in sorted(self.nets.items()):
            crate.signals.subscribe(net, partial(self._on_net, c))

    def reset(self) -> None:
        super().reset()  # regs: ID, CTL (x4, disarmed) and PRE at their reset values
        self.ch = [_Channel() for _ in range(CHANNELS)]

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "channels": {c: n for c, n in sorted(self.nets.items())},
                "sample_hz": self.sample_hz}

    # --- register handlers ---------------------------------------------------------------
    def _high(self, c: int, attr: str) -> int:
        return getattr(self.ch[c], attr) >> 16  # bits 23:16; HI bits 15:8 read 0

    def _low(self, c: int, attr: str) -> int:
        return getattr(self.ch[c], attr) & 0xFFFF

    def _store(self, reg: str, keep: int, value: int) -> None:
        self.regs[reg] = value & keep

    def _preset_value(self, c: int) -> int:
        hi, lo = self._pre[c]
        return self.regs[hi] << 16 | self.regs[lo]

    def _command(self, c: int, value: int) -> None:
        ch = self.ch[c]
        if value & _LATCH:
            ch.ol = ch.counter
        if value & _CLEAR:
            ch.counter = 0
        if value & _PRESET:
            ch.counter = self._preset_value(c)

    def write_GCMD(self, value: int) -> None:
        for c, ch in enumerate(self.ch):
            if value & (1 << c):
                ch.ol = ch.counter

    def _read_status(self, c: int) -> int:
        ch = self.ch[c]
        return ch.status | _A_HIGH[ch.phase] << 8 | _B_HIGH[ch.phase] << 9

    def _clear_flags(self, c: int, value: int) -> None:
        self.ch[c].status &= ~value & _FLAGS

    # --- counting ------------------------------------------------------------------------
    def _mode(self, c: int) -> int:
        return self.regs[self._ctl[c]] & _MODE

    def _counter_steps(self, mode: int, acc_from: int, acc_to: int) -> int:
        """Counter steps while the x4 accumulator goes from ``acc_from`` to ``acc_to``: the
        ÷k prescaler moves at multiples of k (floor division, both directions)."""
        if mode == _HOLD:
            return 0
        k = _PRESCALE[mode]
        return acc_to // k - acc_from // k

    def _count(self, c: int, steps: int) -> None:
        ch = self.ch[c]
        value = ch.counter + steps
        if value > _TOP:
            ch.status |= _OVERFLOW
        elif value < 0:
            ch.status |= _UNDERFLOW
        ch.counter = value % _MODULUS

    def _on_net(self, c: int, net: str, events: Any) -> None:
        if not isinstance(events, QuadratureEvents):
            raise TypeError(
                f"{self.name} channel {c}: net {net!r} carries {type(events).__name__}, not QuadratureEvents; "
                "publish encoder events with Signals.publish_quadrature"
            )
        self.apply_events(c, events)

    def apply_events(self, c: int, ev: QuadratureEvents) -> None:
        """Apply one interval's decoded events to channel ``c`` (faults included)."""
        ch = self.ch[c]
        counts, illegal = int(ev.counts), int(ev.illegal)
        offsets = tuple(int(o) for o in ev.index_offsets) if ev.index_offsets else ()
        ch.stats["intervals"] += 1
        faulted = self.faulted  # no fault armed: fault() would answer None for both
        miss = self.fault("missed_counts") if faulted else None
        if miss is not None and int(miss.get("channel", 0)) == c and ch.missed_left > 0 and counts:
            drop = min(ch.missed_left, abs(counts))
            ch.missed_left -= drop
            sign = 1 if counts > 0 else -1
            counts -= sign * drop
            offsets = tuple(o - sign * min(drop, abs(o)) if o * sign > 0 else o for o in offsets)
        glitch = self.fault("glitch") if faulted else None
        extra = 0
        if glitch is not None and int(glitch.get("channel", 0)) == c and ch.glitch_left != 0:
            extra = int(glitch.get("counts", 0))
            illegal += int(glitch.get("illegal", 1))
            if ch.glitch_left > 0:
                ch.glitch_left -= 1
        ctl_key = self._ctl[c]
        ctl = self.regs[ctl_key]
        mode = ctl & _MODE
        if offsets:
            ch.stats["index"] += len(offsets)
            if ctl & _ARM:  # the first pulse is captured, at the count it arrived at; disarm
                steps = self._counter_steps(mode, ch.acc, ch.acc + offsets[0])
                ch.idx = (ch.counter + steps) % _MODULUS
                ch.status |= _INDEX
                self.regs[ctl_key] = ctl & ~_ARM
        total = counts + extra
        if mode != _HOLD:
            self._count(c, self._counter_steps(mode, ch.acc, ch.acc + total))
            ch.acc += total
        if illegal:
            ch.status |= _ILLEGAL
            ch.stats["illegal"] += illegal
        ch.stats["counts"] += total
        ch.phase = int(ev.phase) % 4

    # --- lanes (batched lockstep) ---------------------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Backplane) -> QuadratureBoard:
        """One board in lane mode holding the B ``boards`` (lane order; same wiring and sampling
        rate, no fault armed). The crate installs it (``attach`` subscribes its channels' nets
        on ``crate.signals``, as for a scalar board); from then on its register reads return
        lane values and the nets carry lane-mode events."""
        quads: list[QuadratureBoard] = []
        for b in boards:
            if type(b) is not cls or not isinstance(b, QuadratureBoard):
                raise NotImplementedError(f"{boards[0].name}: lanes of one board type only, got {type(b).__name__}")
            quads.append(b)
        first = quads[0]
        for b in quads:
            if b.nets != first.nets or b.sample_hz != first.sample_hz:
                raise NotImplementedError(f"{first.name}: the lanes' decoders are wired or sampled differently")
            if b.faulted:
                raise NotImplementedError(f"{first.name}: a decoder with a fault injected runs scalar")
        board = cls(first.name, nets=first.nets, sample_hz=first.sample_hz)
        board._lanes_from(quads)
        return board

    def _lanes_from(self, boards: Sequence[QuadratureBoard]) -> None:
        """Turn this new board into the lane-mode board of ``boards``: state stacked, the lane
        handlers bound in place of the scalar ones (before any cycle resolves them), so the
        scalar board's code is untouched."""
        self.size_lanes = len(boards)
        self._stack_regs(boards)
        self.lane_ch = [_LaneChannel([b.ch[c] for b in boards]) for c in range(CHANNELS)]
        self.ch = []  # the scalar channels are not used in lane mode (an access would fail loudly)
        for c in range(CHANNELS):
            for reg, attr in (("OL", "ol"), ("CNT", "counter"), ("IDX", "idx")):
                setattr(self, f"read_{_name(c, reg + '_HI')}", partial(self._lane_high, c, attr))
                setattr(self, f"read_{_name(c, reg + '_LO')}", partial(self._lane_low, c, attr))
            setattr(self, f"write_{_name(c, 'CMD')}", partial(self._lane_command, c))
            setattr(self, f"read_{_name(c, 'STATUS')}", partial(self._lane_read_status, c))
            setattr(self, f"write_{_name(c, 'STATUS')}", partial(self._lane_clear_flags, c))
        self.write_GCMD = self._lane_gcmd  # type: ignore[method-assign]
        self.apply_events = self._lane_apply_events  # type: ignore[method-assign]
        self.reset = self._lane_reset  # type: ignore[method-assign]
        self.inject = self._lane_inject  # type: ignore[method-assign]

    def _lane_reset(self) -> None:
        RegisterBoard.reset(self)
        self.lane_ch = [_LaneChannel([_Channel()] * self.size_lanes) for _ in range(CHANNELS)]

    def _lane_inject(self, name: str, **params: Any) -> None:
        raise NotImplementedError(f"{self.name}: faults are injected per instance; a run with faults runs scalar")

    def _lane_high(self, c: int, attr: str) -> LaneValue:
        return getattr(self.lane_ch[c], attr) >> 16

    def _lane_low(self, c: int, attr: str) -> LaneValue:
        return getattr(self.lane_ch[c], attr) & 0xFFFF

    def _lane_command(self, c: int, value: LaneValue) -> None:
        ch = self.lane_ch[c]
        counter = ch.counter
        if isinstance(value, np.ndarray):  # a command per lane
            ch.ol = np.where(value & _LATCH != 0, counter, ch.ol)
            counter = np.where(value & _CLEAR != 0, 0, counter)
            ch.counter = np.where(value & _PRESET != 0, self._preset_value(c), counter)
            return
        if value & _LATCH:
            ch.ol = counter
        if value & _CLEAR:
            ch.counter = np.zeros_like(counter)
        if value & _PRESET:
            ch.counter = np.zeros_like(counter) + self._preset_value(c)

    def _lane_gcmd(self, value: LaneValue) -> None:
        for c, ch in enumerate(self.lane_ch):
            bit = value & (1 << c)
            if isinstance(bit, np.ndarray):
                ch.ol = np.where(bit != 0, ch.counter, ch.ol)
            elif bit:
                ch.ol = ch.counter

    def _lane_read_status(self, c: int) -> LaneValue:
        ch = self.lane_ch[c]
        return ch.status | _AB_BITS[ch.phase]

    def _lane_clear_flags(self, c: int, value: LaneValue) -> None:
        ch = self.lane_ch[c]
        ch.status = ch.status & (~value & _FLAGS)

    def _lane_apply_events(self, c: int, ev: QuadratureEvents) -> None:
        """:meth:`apply_events` for B lanes: ``ev`` carries lane values (``emulators.plant.lanes.lane_events``;
        a plain scalar object is every lane's). The same rules, lane by lane, as array operations."""
        ch = self.lane_ch[c]
        counts, illegal = ev.counts, ev.illegal
        offsets: Any = ev.index_offsets  # lane mode: a tuple of B tuples
        stats = ch.stats
        stats["intervals"] = stats["intervals"] + 1
        ctl_key = self._ctl[c]
        regs: dict[str, Any] = self.regs  # lane values
        ctl = regs[ctl_key]
        mode = ctl & _MODE
        acc, counter = ch.acc, ch.counter
        if offsets and not isinstance(offsets[0], tuple):  # a scalar object: every lane's offsets
            offsets = (offsets,) * self.size_lanes
        if any(offsets):  # an index pulse in some lane: the first one captured where armed, then disarm
            n = self.size_lanes
            seen = np.fromiter(map(len, offsets), dtype=np.int64, count=n)
            first = np.fromiter((o[0] if o else 0 for o in offsets), dtype=np.int64, count=n)
            stats["index"] = stats["index"] + seen
            capture = (seen > 0) & (ctl & _ARM != 0)
            steps = _counter_steps_lanes(mode, acc, acc + first)
            ch.idx = np.where(capture, (counter + steps) % _MODULUS, ch.idx)
            ch.status = np.where(capture, ch.status | _INDEX, ch.status)
            regs[ctl_key] = np.where(capture, ctl & ~_ARM, ctl)
        counting = mode != _HOLD
        value = counter + _counter_steps_lanes(mode, acc, acc + counts)
        flags = np.where(value > _TOP, _OVERFLOW, np.where(value < 0, _UNDERFLOW, 0))
        ch.counter = value % _MODULUS
        ch.acc = np.where(counting, acc + counts, acc)
        ch.status = ch.status | flags | np.where(illegal != 0, _ILLEGAL, 0)
        stats["illegal"] = stats["illegal"] + illegal
        stats["counts"] = stats["counts"] + counts
        ch.phase = ev.phase % 4 + np.zeros_like(counter)

    # --- faults --------------------------------------------------------------------------
    def _fault_changed(self, name: str) -> None:
        f = self.fault(name)
        if f is None:
            return
        c = int(f.get("channel", 0))
        if not 0 <= c < CHANNELS:
            self.clear_fault(name)
            raise ValueError(f"{self.name}: fault {name} channel {c} is not 0..{CHANNELS - 1}")
        if name == "glitch":
            self.ch[c].glitch_left = int(f.get("intervals", 1))
        elif name == "missed_counts":
            self.ch[c].missed_left = abs(int(f.get("counts", 1)))
        elif name == "counter_jump":
            self._count(c, int(f.get("counts", 1)))


def quad_from_config(name: str, cfg, ctx) -> QuadratureBoard:
    """Crate-file factory (``type = "quad"``)::

        [[crate.board]]
        type = "quad"
        name = "quad0"
        space = "A16"
        base = 0x5000
        channels = ["j1.encoder", "j2.encoder", "", ""]   # net per channel ("" = unwired)
        sample_hz = 1e6                                   # decoder input sampling rate
    """
    nets: dict[int, str] = {}
    if "channels" in cfg:
        raw = cfg.raw("channels")
        if not isinstance(raw, list) or len(raw) > CHANNELS or not all(isinstance(x, str) for x in raw):
            raise cfg.error("channels", f"a list of up to {CHANNELS} net names (\"\" = unwired)", raw)
        nets = {c: n for c, n in enumerate(raw) if n}
    sample_hz = cfg.get_float("sample_hz", DEFAULT_SAMPLE_HZ, min=1.0, max=1e9)
    return QuadratureBoard(name, nets=nets, sample_hz=sample_hz)
