"""Register-level emulator of the 16-channel 12-bit ADC board, written from ``docs/boards/adc.md``.

A second reading of the board, independent of the driver (:mod:`hal.adc_dac`, which it does not
import): its register map, bit masks, ID, gain-code table and quantizer are its own literal
Python, written from the doc's register table, gain table and conversion formula. Tests check
both this map and the driver's against the doc's table (tests/hal/test_adc.py), never against
each other.

Behaviour (as the real boards of the era: see ``docs/boards/adc.md``):

* A conversion takes ``conversion_time_ns`` of simulated time (default 15 µs); a scan of
  channels 0..LAST takes (LAST+1) conversions back to back.
* Sample-and-hold: each channel's analog net is sampled at *its* conversion start; the code
  appears in DATA (single) or BUFn (scan) at its conversion end.
* Reading DATA or a BUF word while BUSY returns the stale word and sets CSR.EARLY; a start or
  scan while BUSY is ignored and sets CSR.OVERRUN.
* End of conversion/scan sets DONE and, with IRQ_EN and IRQ_LEVEL ≠ 0, IRQ_PEND and an
  interrupt with the VECTOR register's status/ID. Release is **RORA**: the request stays until
  the host writes 1 to CSR.IRQ_PEND (or clears IRQ_EN, starts again, or resets).
* Analog front end per sample: ``v = net + noise`` (Gaussian; rms = √(noise_rms_v² + burst² +
  Σ extra sources²)), then the channel's error ``v·(1 + gain_error) + offset_v``, then the PGA
  and quantizer (the doc's formula ``code = floor((v − V₀)/LSB + ½)``, clipped at the rails
  0 and 0xFFF: :meth:`AdcBoard.sample`).
* A D8 write of the CSR's high byte (+0x02) writes the configuration only; the low byte's
  strobes and write-1-to-clear flags see zeros (:meth:`AdcBoard._resolve_write`).

Faults: ``stuck_channel(channel, code)``, ``noise_burst(rms_v, channels=None)``.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`AdcBoard.from_lanes` stacks the boards of B
instances into one board whose registers hold a value per lane and whose conversions convert
every lane, each from its own noise stream (the section "lanes" at the end of this module).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any, ClassVar

import numpy as np

from emulators.board import Backplane, Board, RegisterBoard
from emulators.board_factory import BuildContext
from emulators.rng import rng_for
from hal.config import ConfigTable
from hal.lanes import LaneSet, stack
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the board, as docs/boards/adc.md states it ------------------------------------------------
ADC_BOARD_ID = 0xAD16  #: the ID register ("Essentials" and the register table)
ADC_CHANNELS = 16
CODE_MAX = 0xFFF  #: 12-bit codes 0..0xFFF

#: the doc's register table, row by row: (offset, name, access, reset, D8 too, fields as
#: (name, msb, lsb) — the doc's ``[msb:lsb]``)
_DATA_WORD = (("CHANNEL", 15, 12), ("CODE", 11, 0))
_TABLE: tuple[tuple[int, str, Access, int, bool, tuple[tuple[str, int, int], ...]], ...] = (
    (0x00, "ID", Access.RO, 0xAD16, True, ()),
    (0x02, "CSR", Access.RW, 0x0000, True, (
        ("RESET", 15, 15), ("RANGE", 12, 12), ("IRQ_LEVEL", 11, 9), ("IRQ_EN", 8, 8),
        ("IRQ_PEND", 7, 7), ("OVERRUN", 5, 5), ("EARLY", 4, 4), ("DONE", 3, 3), ("BUSY", 2, 2),
        ("SCAN", 1, 1), ("START", 0, 0))),
    (0x04, "CHAN", Access.RW, 0x0000, False, (("GAIN", 5, 4), ("CHANNEL", 3, 0))),
    (0x06, "DATA", Access.RO, 0x0000, False, _DATA_WORD),
    (0x08, "VECTOR", Access.RW, 0x000F, False, (("VECTOR", 7, 0),)),
    (0x0A, "SCAN_LAST", Access.RW, 0x000F, False, (("LAST", 3, 0),)),
    (0x0C, "SCAN_GAIN0", Access.RW, 0x0000, False, tuple((f"CH{7 - k}", 15 - 2 * k, 14 - 2 * k) for k in range(8))),
    (0x0E, "SCAN_GAIN1", Access.RW, 0x0000, False, tuple((f"CH{15 - k}", 15 - 2 * k, 14 - 2 * k) for k in range(8))),
    *((0x20 + 2 * k, f"BUF{k}", Access.RO, 0x0000, False, _DATA_WORD) for k in range(16)),
)

REGMAP = RegisterMap(
    "adc16",
    0x40,  # the window: BUF15 at 0x3E is the last register
    AddressSpace.A16,
    tuple(
        Register(name, offset, Width.D16, access, tuple(Field(f, lsb, msb - lsb + 1) for f, msb, lsb in fields),
                 reset=reset, also=(Width.D8,) if d8 else ())
        for offset, name, access, reset, d8, fields in _TABLE
    ),
    doc="emulated 16-channel 12-bit ADC (docs/boards/adc.md)",
)

_CSR = REGMAP["CSR"]
_F = {f.name: f for f in _CSR.fields}
_BIT = {name: f.mask for name, f in _F.items()}
#: CSR bits a write of 1 clears (EARLY, OVERRUN, IRQ_PEND) and the configuration bits a write
#: stores (IRQ_EN, IRQ_LEVEL, RANGE): the doc's "write" column of the CSR bit table
_W1C = _BIT["EARLY"] | _BIT["OVERRUN"] | _BIT["IRQ_PEND"]
_CONFIG = _BIT["IRQ_EN"] | _BIT["IRQ_LEVEL"] | _BIT["RANGE"]
_CSR_OFFSET = _CSR.offset

#: the doc's gain table: gain → gain code, and the full scale FS = 10 V / gain of each gain code
_CODE_OF_GAIN = {1: 0, 2: 1, 4: 2, 8: 3}
_FULL_SCALE_V = (10.0, 5.0, 2.5, 1.25)

DEFAULT_CONVERSION_TIME_NS = 15_000
_NORMAL_BLOCK = 256  #: noise normals drawn per numpy call

NoiseSource = Callable[[], float]


class AdcBoard(RegisterBoard):
    """Emulated ADC board.

    Args:
        name: board name in the crate.
        wiring: channel → analog net name; unwired channels read 0 V.
        noise_rms_v: input-referred Gaussian noise (V rms) on every conversion.
        offset_v: per-channel offset error (V), 16 values (default 0).
        gain_error: per-channel gain error (fraction, 0.001 = +0.1 %), 16 values (default 0).
        conversion_time_ns: time of one conversion.
        seed: run seed; the noise stream is ``rng_for(seed, name, "noise")``.
    """

    TYPE = "adc"
    REGMAP = REGMAP
    irq_release = "rora"
    #: the per-lane state of a board of lanes (:meth:`from_lanes`); None: one instance
    _lanes: _AdcLanes | None = None
    FAULTS: ClassVar[dict[str, str]] = {
        "stuck_channel": "channel=N, code=C: channel N always converts to code C (0..0xFFF)",
        "noise_burst": "rms_v=V[, channels=[...]]: extra Gaussian noise (V rms) on all or listed channels",
    }

    def __init__(
        self,
        name: str,
        *,
        wiring: Mapping[int, str] | None = None,
        noise_rms_v: float = 0.0,
        offset_v: Sequence[float] | None = None,
        gain_error: Sequence[float] | None = None,
        conversion_time_ns: int = DEFAULT_CONVERSION_TIME_NS,
        seed: int = 0,
    ) -> None:
        self.wiring: dict[int, str] = {}
        for ch, net in (wiring or {}).items():
            if not 0 <= int(ch) < ADC_CHANNELS:
                raise ValueError(f"{name}: wiring channel {ch} is not 0..{ADC_CHANNELS - 1}")
            self.wiring[int(ch)] = str(net)
        if noise_rms_v < 0:
            raise ValueError(f"{name}: noise_rms_v must be >= 0 V, got {noise_rms_v}")
        self.noise_rms_v = float(noise_rms_v)
        self.offset_v = per_channel(name, "offset_v", offset_v, ADC_CHANNELS)
        self.gain_error = per_channel(name, "gain_error", gain_error, ADC_CHANNELS)
        if conversion_time_ns <= 0:
            raise ValueError(f"{name}: conversion_time_ns must be > 0")
        self.conversion_time_ns = int(conversion_time_ns)
        self._rng = rng_for(seed, name, "noise")
        self._normals: list[float] = []  # drawn ahead from _rng (see _normal)
        self._normal_next = 0
        self._noise_sources: list[NoiseSource] = []
        #: what each noise source is, as data (:meth:`add_switching_noise`: its nets and level),
        #: or None for an opaque ``add_noise_source`` callable (a board with one cannot run in lanes)
        self._noise_specs: list[tuple[tuple[str, ...], float] | None] = []
        self._gen = 0  # bumped on reset: events of an aborted conversion are ignored
        self._busy = False
        self.conversions = 0  #: number of channel conversions completed (diagnostic)
        super().__init__(name)

    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> AdcBoard:
        """One board of lanes holding ``boards`` (the same ADC of B instances built and set up as
        scalar runs build them, in lane order): registers, parameters and noise streams stacked,
        for ``crate`` (a crate of lanes) to install where they were (the section "lanes" below)."""
        adcs = [b for b in boards if type(b) is cls]
        if len(adcs) != len(boards):
            raise NotImplementedError(f"{boards[0].name}: other board types cannot stack into one {cls.__name__}")
        return _stack_adc_boards(cls, adcs, crate)

    # --- power-up / reset ---------------------------------------------------------------
    def reset(self) -> None:
        super().reset()
        self._gen += 1
        self._busy = False

    # --- analog front end ---------------------------------------------------------------
    def add_noise_source(self, fn: NoiseSource) -> None:
        """Add a noise contributor: ``fn()`` returns extra rms volts at the conversion instant
        (e.g. H-bridge switching noise coupling into the inputs while the bridge runs)."""
        self._noise_sources.append(fn)
        self._noise_specs.append(None)

    def add_switching_noise(self, nets: Sequence[str], level_v: float) -> None:
        """Add ``level_v`` rms of noise to every conversion made while any of the analog ``nets``
        (e.g. H-bridge PWM duty nets) is above 0 V: switching noise coupling into the inputs while
        a bridge drives. Kept as data too, so that a lane-mode board can rebuild it
        (:meth:`from_lanes`). Call it once the board is in its crate (it reads the crate's nets)."""
        if self.crate is None:
            raise ValueError(f"{self.name}: switching noise reads the crate's nets; install the board first")
        names, level = tuple(str(n) for n in nets), float(level_v)
        analog = self.crate.signals.analog  # read directly: called at every conversion

        def noise() -> float:
            for n in names:
                if analog.get(n, 0.0) > 0.0:
                    return level
            return 0.0

        self._noise_sources.append(noise)
        self._noise_specs.append((names, level))

    def input_volts(self, channel: int) -> float:
        """The noiseless voltage at ``channel``'s input pin now (0 V if unwired)."""
        net = self.wiring.get(channel)
        if net is None or self.crate is None:
            return 0.0
        return self.crate.signals.get_analog(net)

    def _noise_rms(self, channel: int) -> float:
        var = self.noise_rms_v**2
        if self.faulted:
            burst = self.fault("noise_burst")
            if burst is not None:
                chans = burst.get("channels")
                if chans is None or channel in chans:
                    var += float(burst.get("rms_v", 0.0)) ** 2
        for fn in self._noise_sources:
            var += float(fn()) ** 2
        return math.sqrt(var)

    def _normal(self) -> float:
        """The next standard normal of the noise stream. Drawn in blocks: a block holds the
        same numbers, in the same order, as one ``standard_normal()`` call per sample would
        give (numpy's Generator fills arrays from the same stream), without a numpy call and
        a numpy scalar per sample. The stream is this board's own."""
        i = self._normal_next
        if i >= len(self._normals):
            i = self._refill_normals()
        self._normal_next = i + 1
        return self._normals[i]

    def _refill_normals(self) -> int:
        """Draw the next block of normals; returns the index of the next one (0)."""
        self._normals = self._rng.standard_normal(_NORMAL_BLOCK).tolist()
        return 0

    def noise_state(self, lane: int = 0) -> tuple[Mapping[str, Any], tuple[float, ...]]:
        """The noise stream where it stands: its generator's state and the normals drawn ahead
        and not used yet (of ``lane``, on a board of lanes). Two boards with equal states draw the
        same noise from now on."""
        if self._lanes is not None:
            return self._lanes.noise_state(lane)
        return self._rng.bit_generator.state, tuple(self._normals[self._normal_next:])

    def sample(self, channel: int, gain: int, bipolar: bool = True) -> int:
        """Sample-and-hold plus conversion of ``channel`` now at ``gain`` (1, 2, 4 or 8) in the
        ±10 V/gain (``bipolar``) or 0..10 V/gain range: the 12-bit code. The reference path,
        faults included; without a fault armed a conversion runs the same steps inline
        (:meth:`_Conversion.sample`)."""
        gcode = _CODE_OF_GAIN.get(gain)
        if gcode is None:
            raise ValueError(f"{self.name}: gain {gain!r} is not one of 1, 2, 4, 8")
        return self._sample_code(channel, gcode, bipolar)

    def _sample_code(self, channel: int, gcode: int, bipolar: bool) -> int:
        stuck = self.fault("stuck_channel")
        if stuck is not None and int(stuck.get("channel", -1)) == channel:
            return int(stuck.get("code", 0)) & CODE_MAX
        v = self.input_volts(channel)
        sigma = self._noise_rms(channel)
        if sigma > 0:
            v += sigma * self._normal()
        v = v * (1.0 + self.gain_error[channel]) + self.offset_v[channel]
        return quantize(v, bipolar, gcode)

    # --- registers ----------------------------------------------------------------------
    def read_CSR(self) -> int:
        return self.regs["CSR"] | (_BIT["BUSY"] if self._busy else 0)

    def write_CSR(self, value: int) -> None:
        if value & _BIT["RESET"]:
            self.reset()
            return
        csr = self.regs["CSR"]
        csr &= ~(value & _W1C)
        csr = (csr & ~_CONFIG) | (value & _CONFIG)
        self.regs["CSR"] = csr
        if (value & _BIT["IRQ_PEND"]) or not (csr & _BIT["IRQ_EN"]):
            self._drop_irq()
        if value & (_BIT["START"] | _BIT["SCAN"]):
            if self._busy:
                self.regs["CSR"] |= _BIT["OVERRUN"]
            elif value & _BIT["SCAN"]:
                self._start(list(range((self.regs["SCAN_LAST"] & 0xF) + 1)), scan=True)
            else:
                self._start([self.regs["CHAN"] & 0xF], scan=False)

    def write_CHAN(self, value: int) -> None:
        self.regs["CHAN"] = value & 0x3F

    def write_VECTOR(self, value: int) -> None:
        self.regs["VECTOR"] = value & 0xFF

    def write_SCAN_LAST(self, value: int) -> None:
        self.regs["SCAN_LAST"] = value & 0xF

    def read_DATA(self) -> int:
        self._note_read()
        return self.regs["DATA"]

    def _resolve_write(self, offset: int, width: Width) -> Callable[[int], None]:
        """A D8 write of the CSR's high byte (+0x02) is a configuration write: the action and
        status byte sees zeros, so it neither starts a conversion nor clears a flag (the
        generic byte merge would write the stored flags back as ones, clearing them)."""
        if offset == _CSR_OFFSET and width is Width.D8:
            return self._write_csr_high_byte
        return super()._resolve_write(offset, width)

    def _write_csr_high_byte(self, value: int) -> None:
        self.write_CSR((value & 0xFF) << 8)

    def _resolve_read(self, offset: int, width: Width) -> Callable[[], int]:
        read = super()._resolve_read(offset, width)
        reg = self.REGMAP.containing(offset)
        if reg is None or not reg.name.startswith("BUF"):
            return read
        def read_buffer() -> int:  # a BUF word read while BUSY sets CSR.EARLY (_note_read)
            value = read()
            if self._busy:
                self.regs["CSR"] |= _BIT["EARLY"]
            return value

        return read_buffer

    def _note_read(self) -> None:
        if self._busy:
            self.regs["CSR"] |= _BIT["EARLY"]

    # --- conversion sequencing ----------------------------------------------------------
    def _start(self, channels: list[int], *, scan: bool) -> None:
        self._busy = True
        self.regs["CSR"] &= ~_BIT["DONE"]
        self._drop_irq()
        _Conversion(self, channels, scan, self._gen).begin()

    def _converted(self, conv: _Conversion) -> None:
        """End of one conversion of ``conv`` (scheduled by :meth:`_Conversion.begin`).

        The next conversion of a scan starts at this instant. When its end would be the clock's
        next event anyway (:meth:`SimClock.free_until`: nothing else is queued before it and the
        clock is advancing past it), it is done here — sampled now, the time moved to its end,
        its word stored — instead of through the event queue: the same samples at the same
        instants in the same order (a 16-channel scan was 16 queue round trips per tick)."""
        if conv.gen != self._gen:
            return  # reset while converting
        regs, n = self.regs, len(conv.channels)
        clock = self.crate.clock if self.crate is not None else None
        while True:
            self.conversions += 1
            i = conv.i
            ch = conv.channels[i]
            regs[_BUF[ch] if conv.scan else "DATA"] = conv.word
            if i + 1 >= n:
                break
            conv.i = i + 1
            assert clock is not None
            end = clock._now + self.conversion_time_ns  # clock.now_ns
            if not clock.free_until(end):
                conv.begin()
                return
            conv.sample()
            clock._now = end  # as the crate moves the time of a cycle that ends before any event
        self._sequence_done()

    def _sequence_done(self) -> None:
        """End of the last conversion of a start or scan: DONE, and the interrupt if enabled."""
        self._busy = False
        self.regs["CSR"] |= _BIT["DONE"]
        csr = self.regs["CSR"]
        level = _F["IRQ_LEVEL"].get(csr)
        if csr & _BIT["IRQ_EN"] and level:
            self.regs["CSR"] |= _BIT["IRQ_PEND"]
            self.request_irq(level, self.regs["VECTOR"])

    def _drop_irq(self) -> None:
        self.regs["CSR"] &= ~_BIT["IRQ_PEND"]
        self.release_irq()

    # --- crate hooks ---------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        return {
            "type": self.TYPE,
            "id": f"0x{ADC_BOARD_ID:04X}",
            "channels": ADC_CHANNELS,
            "wired": len(self.wiring),
            "conversion_us": self.conversion_time_ns / 1000,
        }


class _Conversion:
    """One single conversion or scan in progress: one object per start, not per sample; the
    same bound callback is scheduled at each conversion's end."""

    __slots__ = ("board", "channels", "end", "gains", "gen", "i", "range", "scan", "word")

    def __init__(self, board: AdcBoard, channels: list[int], scan: bool, gen: int) -> None:
        self.board, self.channels, self.scan, self.gen = board, channels, scan, gen
        self.i = 0
        self.word = 0
        self.end = partial(board._converted, self)

    def begin(self) -> None:
        """Sample-and-hold of conversion ``i`` now; its word appears at the conversion's end."""
        self.sample()
        b = self.board
        assert b.crate is not None
        clock = b.crate.clock
        clock.schedule(clock.now_ns + b.conversion_time_ns, self.end)

    def sample(self) -> None:
        """Sample-and-hold of conversion ``i`` now: its word (stored at the conversion's end).

        Without a fault armed, :meth:`AdcBoard.sample`, its noise draw and :func:`quantize` run
        inline here: the same reads, sums
        and roundings in the same order, one Python call per conversion instead of five (a tick
        converts 20-50 channels)."""
        b = self.board
        ch = self.channels[self.i]
        regs = b.regs
        bipolar = not regs["CSR"] & _RANGE  # CSR.RANGE, read at each conversion's start
        if self.scan:  # the channel's SCAN_GAIN field, or CHAN.GAIN: read at each conversion's start
            gcode = regs[_SCAN_GAIN[ch >= 8]] >> (2 * (ch % 8)) & 0x3
        else:
            gcode = regs["CHAN"] >> 4 & 0x3
        if b.faulted:
            code = b._sample_code(ch, gcode, bipolar)  # S/H at conversion start
        else:
            net = b.wiring.get(ch)
            crate = b.crate
            v = 0.0 if net is None or crate is None else crate.signals.analog.get(net, 0.0)
            var = b.noise_rms_v**2
            for fn in b._noise_sources:
                var += float(fn()) ** 2
            sigma = math.sqrt(var)
            if sigma > 0:  # b._normal() inline
                i = b._normal_next
                if i >= len(b._normals):
                    i = b._refill_normals()
                b._normal_next = i + 1
                v += sigma * b._normals[i]
            v = v * (1.0 + b.gain_error[ch]) + b.offset_v[ch]
            if v != v:
                raise ValueError("ADC input is NaN")  # as quantize
            v0, lsb = _V0_LSB[bipolar][gcode]
            code = math.floor((v - v0) / lsb + 0.5)
            code = 0 if code < 0 else CODE_MAX if code > CODE_MAX else code
        self.word = (ch << 12) | code


_BUF = tuple(f"BUF{ch}" for ch in range(ADC_CHANNELS))
_SCAN_GAIN = ("SCAN_GAIN0", "SCAN_GAIN1")
_RANGE = _BIT["RANGE"]
#: (V₀ = volts of code 0, LSB = volts per code) per [unipolar, bipolar] and gain code 0..3, from
#: the doc: 0..10 V/gain straight binary V₀ = 0, LSB = FS/4096; ±10 V/gain offset binary
#: V₀ = −FS, LSB = 2·FS/4096 (FS = 10 V/gain: every one of these floats is exact)
_V0_LSB: tuple[tuple[tuple[float, float], ...], ...] = (
    tuple((0.0, fs / 4096) for fs in _FULL_SCALE_V),
    tuple((-fs, 2 * fs / 4096) for fs in _FULL_SCALE_V),
)


def quantize(volts: float, bipolar: bool, gain_code: int) -> int:
    """The PGA and quantizer of the doc: ``code = floor((volts − V₀)/LSB + ½)``, clipped to
    0..0xFFF (the converter saturates at the rails, never wraps). A NaN input is a modelling
    bug, not a voltage: ``ValueError``."""
    if volts != volts:
        raise ValueError("ADC input is NaN")
    v0, lsb = _V0_LSB[bipolar][gain_code]
    code = math.floor((volts - v0) / lsb + 0.5)
    return 0 if code < 0 else CODE_MAX if code > CODE_MAX else code


def per_channel(name: str, key: str, values: Sequence[float] | None, channels: int) -> tuple[float, ...]:
    """A board's per-channel figure (``offset_v``, ``gain_error``): one value per channel, all 0.0
    when none is given (every analog board emulator's)."""
    if values is None:
        return (0.0,) * channels
    if len(values) != channels:
        raise ValueError(f"{name}: {key} needs {channels} values (one per channel), got {len(values)}")
    return tuple(float(v) for v in values)


def wiring_from_config(cfg: ConfigTable, channels: int) -> dict[int, str]:
    """Read a ``[crate.board.wiring]`` table (``"3" = "pot1"``) into ``{3: "pot1"}``."""
    if "wiring" not in cfg:
        return {}
    table = cfg.table("wiring")
    out: dict[int, str] = {}
    for key in table.keys():
        if not key.isdigit() or not 0 <= int(key) < channels:
            raise table.error(key, f"a channel number 0..{channels - 1}", key)
        out[int(key)] = table.get_str(key)
    return out


def adc_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> AdcBoard:
    """Crate-file factory for ``type = "adc"``.

    Keys: ``wiring`` (table channel → net), ``noise_rms_v``, ``offset_v`` and ``gain_error``
    (16 numbers each), ``conversion_time_us``. The noise seed is the crate build seed.
    """
    return AdcBoard(
        name,
        wiring=wiring_from_config(cfg, ADC_CHANNELS),
        noise_rms_v=cfg.get_float("noise_rms_v", 0.0, min=0.0, max=10.0),
        offset_v=cfg.floats("offset_v", None, length=ADC_CHANNELS) if "offset_v" in cfg else None,
        gain_error=cfg.floats("gain_error", None, length=ADC_CHANNELS) if "gain_error" in cfg else None,
        conversion_time_ns=round(cfg.get_float("conversion_time_us", DEFAULT_CONVERSION_TIME_NS / 1000,
                                           min=0.1, max=10_000.0) * 1000),
        seed=ctx.seed,
    )


# --- lanes: B boards of B instances of a rig in one board (batched lockstep, issue #34) ----------
# AdcBoard.from_lanes builds an ordinary AdcBoard and gives it an _AdcLanes, which holds what
# differs per lane and replaces, once, the board's three hooks that branch on a register value or
# compute a sample (write_CSR, _sequence_done, _sample_code); the scalar code above runs unchanged.
# * Sequencing is every lane's: the lanes make the same bus cycles at the same simulated times (one
#   clock), so BUSY, DONE, the scan in progress, the free_until shortcut of _converted and the
#   conversions counter run the scalar code. Where a register value decides the sequence (a CSR
#   write's RESET/START/SCAN bits, SCAN_LAST, the end-of-scan interrupt), the live lanes' common
#   answer is taken and a lane that would have done otherwise is ejected (hal.lanes.LaneSet.decide).
# * The per-sample arithmetic runs on (B,) arrays (_AdcLanes.sample_code) with _Conversion.sample's
#   operations in its order: the same IEEE double operations give the same bits (x**2, sqrt,
#   + - * /, floor are exact in both). A NaN at a lane's input (the scalar run's ValueError) or a
#   value its math.floor cannot convert (±inf: OverflowError) ejects that lane; the others go on.
# * Noise: each lane keeps its scalar board's generator and its block of normals drawn ahead, the
#   blocks as the columns of one (256, B) array, and draws in the scalar order: a lane whose σ is 0
#   at a sample draws nothing there, as its scalar board; a lane's block is refilled from its own
#   generator at the sample where its scalar board refills it.
# * Per-lane parameters (--vary): noise_rms_v, offset_v, gain_error, the switching-noise levels
#   (add_switching_noise, rebuilt on the lane crate's nets, which may hold a value per lane).
# Out of scope (NotImplementedError when stacking or converting): armed faults, opaque
# add_noise_source callables, a conversion in flight, boards differing in wiring or timing.
#: V₀ and LSB of the quantizer as arrays indexed [bipolar, gain code] (the same floats as _V0_LSB)
_V0 = np.array([[v0 for v0, _ in row] for row in _V0_LSB])
_LSB = np.array([[lsb for _, lsb in row] for row in _V0_LSB])
_START_OR_SCAN = _BIT["START"] | _BIT["SCAN"]
_IRQ_LEVEL = _F["IRQ_LEVEL"]


def _stack_adc_boards(cls: type[AdcBoard], boards: Sequence[AdcBoard], crate: Backplane) -> AdcBoard:
    """:meth:`AdcBoard.from_lanes`: one board holding ``boards`` (one per lane, in lane order)."""
    lanes = getattr(crate, "lanes", None)
    if not isinstance(lanes, LaneSet):
        raise ValueError("AdcBoard.from_lanes needs a crate of lanes (its .lanes is a hal.lanes.LaneSet)")
    if len(boards) != lanes.size:
        raise ValueError(f"{len(boards)} ADC boards for a crate of {lanes.size} lanes")
    first = boards[0]
    for b in boards:
        if b.faulted:
            raise NotImplementedError(f"{b.name}: an ADC with a fault armed cannot run in lanes (faults: scalar)")
        if b._busy or b._irq_level:
            raise NotImplementedError(f"{b.name}: an ADC converting or interrupting cannot be stacked (between ticks)")
        if (b.name, b.wiring, b.conversion_time_ns) != (first.name, first.wiring, first.conversion_time_ns):
            raise NotImplementedError(f"{b.name}: ADCs differing in name, wiring or timing cannot run in lanes")
        if None in b._noise_specs:
            raise NotImplementedError(f"{b.name}: an opaque add_noise_source callable cannot run in lanes "
                                      "(add_switching_noise says what a source is)")
        if [s[0] for s in b._noise_specs if s] != [s[0] for s in first._noise_specs if s]:
            raise NotImplementedError(f"{b.name}: ADCs whose switching noise reads different nets cannot run in lanes")
    board = cls(first.name, wiring=first.wiring, conversion_time_ns=first.conversion_time_ns)
    board._stack_regs(boards)
    board.noise_rms_v = stack([b.noise_rms_v for b in boards])
    board.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(ADC_CHANNELS))
    board.gain_error = tuple(stack([b.gain_error[ch] for b in boards]) for ch in range(ADC_CHANNELS))
    board.conversions = stack([b.conversions for b in boards])
    board._gen = first._gen
    board._noise_specs = list(first._noise_specs)  # the nets; the levels are per lane (_AdcLanes)
    board._noise_sources = []  # the scalar closures read the scalar crates' nets: _AdcLanes rebuilds them
    fe = _AdcLanes(board, boards, lanes)
    board._lanes = fe
    # the hooks that branch on register values or compute a sample: selected once, here (the
    # scalar board's code runs unchanged on every other path)
    board.write_CSR = fe.write_CSR  # type: ignore[method-assign]
    board._sequence_done = fe.sequence_done  # type: ignore[method-assign]
    board._sample_code = fe.sample_code  # type: ignore[method-assign,assignment]
    return board


def common_value(lanes: LaneSet, value: Any, reason: str) -> int:
    """The live lanes' common value of a register field that selects what a board of lanes does
    (the most frequent one); lanes holding another are ejected with ``reason``."""
    if not isinstance(value, np.ndarray):
        return int(value)
    live = value[lanes.alive]
    if live.size == 0:
        return int(value[0])
    vals, counts = np.unique(live, return_counts=True)
    v = int(vals[np.argmax(counts)])
    lanes.eject(value != v, reason)
    return v


class LaneNormals:
    """The noise streams of B boards stacked in lanes (one per lane, lane order), each drawn as its
    scalar board draws it: the board's own generator and its block of ``_NORMAL_BLOCK`` normals
    drawn ahead (the boards' ``_rng``, ``_normals``, ``_normal_next``), the blocks as the columns
    of one (256, B) array; a lane's block is refilled from its own generator at the draw where its
    scalar board refills it. Every analog board emulator of lanes draws through one of these."""

    def __init__(self, boards: Sequence[Any]) -> None:
        n = len(boards)
        self.n = n
        self.rngs = [b._rng for b in boards]
        self.normals = np.zeros((_NORMAL_BLOCK, n))
        nexts = []
        for k, b in enumerate(boards):
            if not b._normals:
                nexts.append(_NORMAL_BLOCK)  # nothing drawn yet: the first draw refills, as the scalar's
                continue
            if len(b._normals) != _NORMAL_BLOCK:
                raise NotImplementedError(f"{b.name}: a noise block of {len(b._normals)} normals cannot be stacked")
            self.normals[:, k] = b._normals
            nexts.append(b._normal_next)
        #: the index of each lane's next normal in its column: one int while every lane is at the
        #: same index (every lane drew at every sample: the common case), else an (B,) array
        self.next: int | np.ndarray = nexts[0] if len(set(nexts)) == 1 else np.array(nexts, dtype=np.int64)
        self.index = np.arange(n)

    def _normals_all(self) -> np.ndarray:
        """Every lane's next normal (:meth:`AdcBoard._normal` of each lane)."""
        i = self.next
        if type(i) is int:
            if i >= _NORMAL_BLOCK:
                for k in range(self.n):
                    self._refill(k)
                i = 0
            self.next = i + 1
            return self.normals[i]  # a view, used at once (before any refill)
        return self._normals_some(np.ones(self.n, dtype=bool))

    def _normals_some(self, draw: np.ndarray) -> np.ndarray:
        """The next normal of the lanes where ``draw`` (the others: any number, not drawn)."""
        i = np.full(self.n, self.next, dtype=np.int64) if type(self.next) is int else self.next
        empty = draw & (i >= _NORMAL_BLOCK)
        if empty.any():
            for k in np.flatnonzero(empty).tolist():
                self._refill(k)
            i = np.where(empty, 0, i)
        out = self.normals[np.minimum(i, _NORMAL_BLOCK - 1), self.index]
        i = i + draw
        self.next = int(i[0]) if (i == i[0]).all() else i
        return out

    def _refill(self, k: int) -> None:
        """Lane ``k``'s next block, from its own generator (:meth:`AdcBoard._refill_normals`)."""
        self.normals[:, k] = self.rngs[k].standard_normal(_NORMAL_BLOCK)

    def noise_state(self, k: int) -> tuple[Mapping[str, Any], tuple[float, ...]]:
        """Lane ``k``'s :meth:`AdcBoard.noise_state`."""
        i = int(self.next[k]) if isinstance(self.next, np.ndarray) else self.next
        return self.rngs[k].bit_generator.state, tuple(self.normals[i:, k].tolist())


class _AdcLanes(LaneNormals):
    """What a board of lanes holds per lane, and its lane-mode hooks (the section's comment)."""

    def __init__(self, board: AdcBoard, boards: Sequence[AdcBoard], lanes: LaneSet) -> None:
        n = len(boards)
        self.board, self.lanes, self.n = board, lanes, n
        # the scalar expressions of _Conversion.sample, evaluated per lane in Python (same bits)
        self.var0 = np.array([b.noise_rms_v**2 for b in boards], dtype=float)
        #: every lane has noise of its own (σ > 0 at every sample): every lane draws at every sample
        self.always_draw = bool((self.var0 > 0).all())
        self.gain1 = tuple(stack([1.0 + b.gain_error[ch] for b in boards]) for ch in range(ADC_CHANNELS))
        self.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(ADC_CHANNELS))
        #: the switching-noise sources: (nets, level² per lane); a lane's scalar source returned
        #: its level while a net is > 0 V, and the sample added its square
        specs = [[s for s in b._noise_specs if s is not None] for b in boards]
        self.switching = tuple((nets, np.array([float(lane[k][1]) ** 2 for lane in specs]))
                               for k, (nets, _) in enumerate(specs[0]))
        super().__init__(boards)

    # --- the per-sample arithmetic ---------------------------------------------------------
    def sample_code(self, channel: int, gcode: Any, bipolar: Any) -> np.ndarray:
        """:meth:`AdcBoard._sample_code` of every lane: the codes (B,) int64 of ``channel`` now."""
        b = self.board
        if b.faulted:
            raise NotImplementedError(f"{b.name}: an ADC of lanes cannot convert with a fault armed (faults: scalar)")
        net = b.wiring.get(channel)
        analog = b.crate.signals.analog if b.crate is not None else {}
        with np.errstate(all="ignore"):  # a dead lane's garbage (inf, NaN) must not warn or raise
            v: Any = 0.0 if net is None else analog.get(net, 0.0)
            var = self.var0
            for nets, level_sq in self.switching:
                on: Any = False
                for name in nets:
                    on = on | (analog.get(name, 0.0) > 0.0)
                if on is not False:  # no lane's bridge switching: the scalar sources added 0.0
                    var = var + level_sq * on  # level² · 1.0 or · 0.0: the scalar's level² or 0.0², exactly
            sigma = np.sqrt(var)
            draw = sigma > 0
            if self.always_draw or draw.all():
                v = v + sigma * self._normals_all()
            elif draw.any():
                v = np.where(draw, v + sigma * self._normals_some(draw), v)
            elif not isinstance(v, np.ndarray):
                v = np.full(self.n, v)
            v = v * self.gain1[channel] + self.offset_v[channel]
            if type(bipolar) is bool and type(gcode) is int:
                v0, lsb = _V0_LSB[bipolar][gcode]
            else:  # registers that differ per lane
                rng = np.asarray(bipolar, dtype=np.intp)
                v0, lsb = _V0[rng, gcode], _LSB[rng, gcode]
            x = (v - v0) / lsb + 0.5
            ok = np.isfinite(x)
            if np.count_nonzero(ok) != ok.size:
                nan = v != v
                self.lanes.eject(nan, f"{b.name}: ADC input is NaN (channel {channel})")
                self.lanes.eject(~ok & ~nan, f"{b.name}: ADC input out of the float range (channel {channel})")
                x = np.where(ok, x, 0.0)
            code = np.floor(x)
        np.maximum(code, 0.0, out=code)
        np.minimum(code, float(CODE_MAX), out=code)
        return code.astype(np.int64)

    # --- sequencing: the register values that decide it, one answer for every lane -------
    def common(self, value: Any, reason: str) -> int:
        """:func:`common_value` of this board's lanes."""
        return common_value(self.lanes, value, reason)

    def write_CSR(self, value: Any) -> None:
        """:meth:`AdcBoard.write_CSR` of every lane (``value`` a lane value)."""
        b, lanes = self.board, self.lanes
        if lanes.decide((value & _BIT["RESET"]) != 0, f"{b.name}: CSR.RESET written in some lanes only"):
            b.reset()
            return
        csr = b.regs["CSR"]
        csr &= ~(value & _W1C)
        csr = (csr & ~_CONFIG) | (value & _CONFIG)
        b.regs["CSR"] = csr
        if lanes.decide(((value & _BIT["IRQ_PEND"]) != 0) | ((csr & _BIT["IRQ_EN"]) == 0),
                        f"{b.name}: ADC interrupt released in some lanes only"):
            b._drop_irq()
        if lanes.decide((value & _START_OR_SCAN) != 0, f"{b.name}: ADC conversion started in some lanes only"):
            if b._busy:
                b.regs["CSR"] |= _BIT["OVERRUN"]
            elif lanes.decide((value & _BIT["SCAN"]) != 0, f"{b.name}: ADC scan vs single conversion differs"):
                last = self.common(b.regs["SCAN_LAST"] & 0xF, f"{b.name}: ADC SCAN_LAST differs")
                self.start(list(range(last + 1)), scan=True)
            else:
                self.start([self.common(b.regs["CHAN"] & 0xF, f"{b.name}: ADC CHAN differs")], scan=False)

    def start(self, channels: list[int], *, scan: bool) -> None:
        """:meth:`AdcBoard._start`, with the lane-mode conversion."""
        b = self.board
        b._busy = True
        b.regs["CSR"] &= ~_BIT["DONE"]
        b._drop_irq()
        _LaneConversion(b, channels, scan, b._gen).begin()

    def sequence_done(self) -> None:
        """:meth:`AdcBoard._sequence_done` of every lane."""
        b = self.board
        b._busy = False
        b.regs["CSR"] |= _BIT["DONE"]
        csr = b.regs["CSR"]
        level = _IRQ_LEVEL.get(csr)
        if self.lanes.decide(((csr & _BIT["IRQ_EN"]) != 0) & (level != 0),
                             f"{b.name}: ADC end-of-scan interrupt in some lanes only"):
            b.regs["CSR"] |= _BIT["IRQ_PEND"]
            b.request_irq(self.common(level, f"{b.name}: ADC IRQ level differs"),
                          self.common(b.regs["VECTOR"], f"{b.name}: ADC vector differs"))


class _LaneConversion(_Conversion):
    """A conversion or scan of a lane-mode board: the sequencing is :class:`_Conversion`'s; a
    sample reads the range and gain registers (lane values) and converts every lane."""

    __slots__ = ()

    def sample(self) -> None:
        b = self.board
        ch = self.channels[self.i]
        regs = b.regs
        bipolar = (regs["CSR"] & _RANGE) == 0
        if self.scan:
            gcode = regs[_SCAN_GAIN[ch >= 8]] >> (2 * (ch % 8)) & 0x3
        else:
            gcode = regs["CHAN"] >> 4 & 0x3
        self.word = (ch << 12) | b._sample_code(ch, gcode, bipolar)

