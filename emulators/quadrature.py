"""Emulated 4-channel quadrature decoder board (register map: :mod:`hal.quadrature.quad_regs`).

Input: each channel is wired to a quadrature net; the harness publishes one
:class:`emulators.signals.QuadratureEvents` per interval (``Signals.publish_quadrature``),
made on the plant side by :func:`emulators.encoder_edges.quadrature_events` at this board's
input sampling rate (``sample_hz``). The board applies the interval's counts when the events
arrive.

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

Faults (one channel each, ``channel=n``):

- ``glitch(channel, counts=0, illegal=1, intervals=1)``: noise edges — each of the next
  ``intervals`` intervals gets ``counts`` extra x4 counts and ``illegal`` illegal samples.
- ``missed_counts(channel, counts=N)``: the next ``N`` incoming counts are dropped (at the
  start of each interval, index offsets shift accordingly).
- ``counter_jump(channel, counts=N)``: the live counter jumps by ``N`` steps when injected
  (a hit on the counter chip); wraps set OVERFLOW/UNDERFLOW.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial
from typing import Any, ClassVar

from emulators.board import RegisterBoard
from emulators.signals import QuadratureEvents
from hal.quadrature.quad_regs import (
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
    ST_W1C_MASK,
    reg_name,
)

_DIVIDER = {MODE_CODES[1]: 4, MODE_CODES[2]: 2, MODE_CODES[4]: 1}
DEFAULT_SAMPLE_HZ = 1_000_000.0  #: decoder input sampling rate (HCTL-2016-like filter on a 4 MHz clock)


@dataclass
class _Channel:
    counter: int = 0
    acc: int = 0
    ol: int = 0
    idx: int = 0
    pre: int = 0
    status: int = 0
    ctl: int = MODE_CODES[4]
    phase: int = 0
    glitch_left: int = 0
    missed_left: int = 0
    stats: dict[str, int] = field(default_factory=lambda: {"counts": 0, "illegal": 0, "index": 0, "intervals": 0})


class QuadratureBoard(RegisterBoard):
    """Four 24-bit up/down counters fed by quadrature event summaries.

    Args:
        name: board name in the crate.
        nets: channel → quadrature net name (unwired channels never count).
        sample_hz: the input sampling rate the plant side must use for this board's encoders.
    """

    TYPE = "quad"
    REGMAP = QUAD_REGS
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
        for c in range(CHANNELS):
            for reg, get in (("OL", "ol"), ("CNT", "counter"), ("IDX", "idx"), ("PRE", "pre")):
                setattr(self, f"read_{reg_name(c, reg + '_HI')}", partial(self._get_hi, c, get))
                setattr(self, f"read_{reg_name(c, reg + '_LO')}", partial(self._get_lo, c, get))
            setattr(self, f"write_{reg_name(c, 'PRE_HI')}", partial(self._set_pre, c, True))
            setattr(self, f"write_{reg_name(c, 'PRE_LO')}", partial(self._set_pre, c, False))
            setattr(self, f"read_{reg_name(c, 'CTL')}", partial(self._read_ctl, c))
            setattr(self, f"write_{reg_name(c, 'CTL')}", partial(self._write_ctl, c))
            setattr(self, f"write_{reg_name(c, 'CMD')}", partial(self._command, c))
            setattr(self, f"read_{reg_name(c, 'STATUS')}", partial(self._read_status, c))
            setattr(self, f"write_{reg_name(c, 'STATUS')}", partial(self._write_status, c))
        super().__init__(name)

    def attach(self, crate) -> None:
        super().attach(crate)
        for c, net in sorted(self.nets.items()):
            crate.signals.subscribe(net, partial(self._on_net, c))

    def reset(self) -> None:
        super().reset()
        self.ch = [_Channel() for _ in range(CHANNELS)]

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "channels": {c: n for c, n in sorted(self.nets.items())},
                "sample_hz": self.sample_hz}

    # --- register handlers ---------------------------------------------------------------
    def _get_hi(self, c: int, attr: str) -> int:
        return getattr(self.ch[c], attr) >> 16 & 0xFF

    def _get_lo(self, c: int, attr: str) -> int:
        return getattr(self.ch[c], attr) & 0xFFFF

    def _set_pre(self, c: int, hi: bool, value: int) -> None:
        ch = self.ch[c]
        ch.pre = ((value & 0xFF) << 16 | ch.pre & 0xFFFF) if hi else (ch.pre & 0xFF0000 | value & 0xFFFF)

    def _read_ctl(self, c: int) -> int:
        return self.ch[c].ctl

    def _write_ctl(self, c: int, value: int) -> None:
        self.ch[c].ctl = value & 0x13

    def _command(self, c: int, value: int) -> None:
        ch = self.ch[c]
        if value & CMD_LATCH:
            ch.ol = ch.counter
        if value & CMD_CLEAR:
            ch.counter = 0
        if value & CMD_PRESET:
            ch.counter = ch.pre

    def write_GCMD(self, value: int) -> None:
        for c in range(CHANNELS):
            if value >> c & 1:
                self.ch[c].ol = self.ch[c].counter

    def _read_status(self, c: int) -> int:
        ch = self.ch[c]
        a = int(ch.phase in (1, 2))
        b = int(ch.phase in (2, 3))
        return ch.status | a << 8 | b << 9

    def _write_status(self, c: int, value: int) -> None:
        self.ch[c].status &= ~(value & ST_W1C_MASK)

    # --- counting ------------------------------------------------------------------------
    def _steps(self, c: int, acc_from: int, acc_to: int) -> int:
        mode = self.ch[c].ctl & 3
        if mode == MODE_HOLD:
            return 0
        k = _DIVIDER[mode]
        return acc_to // k - acc_from // k

    def _add(self, c: int, steps: int) -> None:
        ch = self.ch[c]
        raw = ch.counter + steps
        if raw > COUNTER_MASK:
            ch.status |= ST_OVERFLOW
        elif raw < 0:
            ch.status |= ST_UNDERFLOW
        ch.counter = raw % COUNTER_MODULUS

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
        start_counter, start_acc = ch.counter, ch.acc
        if offsets and ch.ctl & 0x10:
            ch.idx = (start_counter + self._steps(c, start_acc, start_acc + offsets[0])) % COUNTER_MODULUS
            ch.status |= ST_INDEX
            ch.ctl &= ~0x10
        if offsets:
            ch.stats["index"] += len(offsets)
        total = counts + extra
        if (ch.ctl & 3) != MODE_HOLD:
            self._add(c, self._steps(c, ch.acc, ch.acc + total))
            ch.acc += total
        if illegal:
            ch.status |= ST_ILLEGAL
            ch.stats["illegal"] += illegal
        ch.stats["counts"] += total
        ch.phase = int(ev.phase) % 4

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
            self._add(c, int(f.get("counts", 1)))


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
