"""Register-level emulator of the VMIC VMIVME-3113A scanning 12-bit ADC (64 channels), written
from ``docs/boards/vmivme-3113a.md``.

A second reading of the board, independent of the driver (:mod:`hal.adc_dac.vmivme3113a`, which
it does not import): its register map, bit masks, ID, ranges and quantizer are its own literal
Python, written from the doc's register table, CSR bit table and conversion formula. Tests check
this map and the driver's against the doc's table, never against each other.

Behaviour (the doc's "Behaviour and timing"):

* The sequencer converts one channel every ``conversion_time_ns`` (default 10 µs). Autoscanning
  (MODE 0, the reset mode) converts channel ``j mod 64`` in the run's ``j``-th slot for ever; the
  scanning modes (3 poll, 4 interrupt) convert channels 0..63 once per START_CONVERT; the
  random modes and the undefined ones stop the sequencer.
* Codes are produced lazily: when the host reads CHk and a conversion of channel k ended since
  the code it holds, the code is made then, from the net's value at that read (the emulator
  keeps no history of the nets). So an autoscan costs nothing between reads.
* CSR read: NEW_DATA_READY (bit 15) and END_OF_SCAN (bit 13) report conversions and full scans
  ended since the previous CSR read, and the read clears them.
* End of a scan in MODE 4, with ICR.INTERRUPT_ENABLE and ICR.LEVEL ≠ 0: an interrupt with IVR's
  vector, released by IACK (ROAK); ICR.INTR_AUTO_CLEAR / FLAG_AUTO_CLEAR clear
  INTERRUPT_ENABLE / FLAG at the IACK.

Faults: ``stuck_channel(channel, code)``, ``noise_burst(rms_v, channels=None)`` (the reference
ADC's kinds), and every board's ``removed``.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`Vmivme3113aBoard.from_lanes` stacks the boards of
B instances into one board whose registers hold a value per lane and whose conversions convert
every lane, each from its own noise stream (the section "lanes" at the end of this module).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any, ClassVar

import numpy as np

from emulators.adc import LaneNormals, common_value, per_channel, wiring_from_config
from emulators.board import Backplane, Board, RegisterBoard
from emulators.board_factory import BuildContext
from emulators.rng import rng_for
from hal.config import ConfigTable
from hal.lanes import LaneSet, stack
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the board, as docs/boards/vmivme-3113a.md states it -----------------------------------------
BOARD_ID = 0x1100  #: the ID register (the source's `bid`)
CHANNELS = 64
CODE_MAX = 0xFFF
DATA_BASE = 0x80  #: CH0; CHk at 0x80 + 2·k

_EXT = ("EXT", 15, 12)
_CODE = ("CODE", 11, 0)
#: the doc's register table, row by row: (offset, name, access, reset, fields as (name, msb, lsb))
_TABLE: tuple[tuple[int, str, Access, int, tuple[tuple[str, int, int], ...]], ...] = (
    (0x00, "ID", Access.RO, 0x1100, ()),
    (0x02, "CSR", Access.RW, 0x0000, (
        ("NEW_DATA_READY", 15, 15), ("FAIL_LED_OFF", 14, 14), ("END_OF_SCAN", 13, 13),
        ("TWOS_COMPLEMENT", 12, 12), ("EN_EXTERNAL_START", 11, 11), ("TIMER_START", 10, 10),
        ("SOFTWARE_RESET", 9, 9), ("MODE", 8, 6))),
    (0x04, "CFR", Access.RW, 0x0000, ()),
    (0x0A, "ICR", Access.RW, 0x0000, (
        ("FLAG", 7, 7), ("FLAG_AUTO_CLEAR", 6, 6), ("EXTERNAL_VECTOR", 5, 5), ("INTERRUPT_ENABLE", 4, 4),
        ("INTR_AUTO_CLEAR", 3, 3), ("LEVEL", 2, 0))),
    (0x12, "IVR", Access.RW, 0x000F, (("VECTOR", 7, 0),)),
    (0x20, "TM0", Access.RW, 0x0000, ()),
    (0x22, "TM1", Access.RW, 0x0000, ()),
    (0x24, "TM2", Access.RW, 0x0000, ()),
    (0x26, "TMC", Access.WO, 0x0000, (("SELECT", 7, 6), ("RW", 5, 4), ("MODE", 3, 1), ("BCD", 0, 0))),
    *((DATA_BASE + 2 * k, f"CH{k}", Access.RO, 0x0000, (_EXT, _CODE)) for k in range(CHANNELS)),
)

REGMAP = RegisterMap(
    "vmivme3113a",
    0x100,  # 64 configuration words, then 64 channel words
    AddressSpace.A16,
    tuple(
        Register(name, offset, Width.D16, access, tuple(Field(f, lsb, msb - lsb + 1) for f, msb, lsb in fields),
                 reset=reset)
        for offset, name, access, reset, fields in _TABLE
    ),
    doc="emulated VMIC VMIVME-3113A 64-channel scanning 12-bit ADC (docs/boards/vmivme-3113a.md)",
)

# CSR bits (the doc's CSR bit table)
_NEW_DATA_READY = 1 << 15
_FAIL_LED_OFF = 1 << 14
_END_OF_SCAN = 1 << 13  # read; a write of 1 here is START_CONVERT
_START_CONVERT = 1 << 13
_TWOS = 1 << 12
_EXT_START = 1 << 11
_TIMER_START = 1 << 10
_SOFTWARE_RESET = 1 << 9
_MODE_SHIFT, _MODE_MASK = 6, 0x7 << 6
#: the CSR bits a write stores and a read returns
_CSR_STORED = _FAIL_LED_OFF | _TWOS | _EXT_START | _TIMER_START | _MODE_MASK
MODE_AUTOSCAN, MODE_RANDOM_POLL, MODE_RANDOM_IRQ, MODE_SCAN_POLL, MODE_SCAN_IRQ = 0, 1, 2, 3, 4

# ICR bits
_ICR_FLAG, _ICR_FAC, _ICR_IE, _ICR_IRAC, _ICR_LEVEL = 1 << 7, 1 << 6, 1 << 4, 1 << 3, 0x7

#: the jumpered input ranges: name → (V₀ = volts of code 0, LSB volts), from the doc's range table
RANGES: dict[str, tuple[float, float]] = {
    "bipolar_10v": (-10.0, 20.0 / 4096),
    "bipolar_5v": (-5.0, 10.0 / 4096),
    "unipolar_10v": (0.0, 10.0 / 4096),
}
DEFAULT_CONVERSION_TIME_NS = 10_000
_NORMAL_BLOCK = 256  #: noise normals drawn per numpy call


def quantize(volts: float, input_range: str) -> int:
    """The doc's quantizer: ``floor((V − V₀)/LSB + ½)`` clipped to 0..0xFFF (offset binary)."""
    if volts != volts:
        raise ValueError("ADC input is NaN")
    v0, lsb = RANGES[input_range]
    code = math.floor((volts - v0) / lsb + 0.5)
    return 0 if code < 0 else CODE_MAX if code > CODE_MAX else code


def data_word(code: int, twos_complement: bool) -> int:
    """The CHk word of an offset-binary code: the code itself, or its MSB inverted and
    sign-extended into bits 15:12 (the doc's "Data words")."""
    if not twos_complement:
        return code
    tc = code ^ 0x800
    return tc | 0xF000 if tc & 0x800 else tc


class _Run:
    """One run of the sequencer: started at ``start_ns``, ``limit`` conversions (None: autoscan)."""

    __slots__ = ("ident", "limit", "start_ns")

    def __init__(self, ident: int, start_ns: int, limit: int | None) -> None:
        self.ident, self.start_ns, self.limit = ident, start_ns, limit


class Vmivme3113aBoard(RegisterBoard):
    """Emulated VMIVME-3113A.

    Args:
        name: board name in the crate.
        wiring: channel → analog net; unwired channels read 0 V.
        input_range: the range jumpers: ``"bipolar_10v"``, ``"bipolar_5v"`` or ``"unipolar_10v"``.
        noise_rms_v: input-referred Gaussian noise (V rms) on every conversion.
        offset_v, gain_error: per-channel errors (64 values each; default 0).
        conversion_time_ns: one conversion (default 10 µs).
        seed: run seed; the noise stream is ``rng_for(seed, name, "noise")``.
    """

    TYPE = "vmivme-3113a"
    REGMAP = REGMAP
    irq_release = "roak"
    #: the per-lane state of a board of lanes (:meth:`from_lanes`); None: one instance
    _lanes: _Vmi3113aLanes | None = None
    FAULTS: ClassVar[dict[str, str]] = {
        "stuck_channel": "channel=N, code=C: channel N always converts to code C (offset binary 0..0xFFF)",
        "noise_burst": "rms_v=V[, channels=[...]]: extra Gaussian noise (V rms) on all or listed channels",
    }

    def __init__(
        self,
        name: str,
        *,
        wiring: Mapping[int, str] | None = None,
        input_range: str = "bipolar_10v",
        noise_rms_v: float = 0.0,
        offset_v: Sequence[float] | None = None,
        gain_error: Sequence[float] | None = None,
        conversion_time_ns: int = DEFAULT_CONVERSION_TIME_NS,
        seed: int = 0,
    ) -> None:
        self.wiring: dict[int, str] = {}
        for ch, net in (wiring or {}).items():
            if not 0 <= int(ch) < CHANNELS:
                raise ValueError(f"{name}: wiring channel {ch} is not 0..{CHANNELS - 1}")
            self.wiring[int(ch)] = str(net)
        if input_range not in RANGES:
            raise ValueError(f"{name}: input_range {input_range!r} is not one of {', '.join(RANGES)}")
        self.input_range = input_range
        if noise_rms_v < 0:
            raise ValueError(f"{name}: noise_rms_v must be >= 0 V, got {noise_rms_v}")
        self.noise_rms_v = float(noise_rms_v)
        self.offset_v = per_channel(name, "offset_v", offset_v, CHANNELS)
        self.gain_error = per_channel(name, "gain_error", gain_error, CHANNELS)
        if conversion_time_ns <= 0:
            raise ValueError(f"{name}: conversion_time_ns must be > 0")
        self.conversion_time_ns = int(conversion_time_ns)
        self._rng = rng_for(seed, name, "noise")
        self._normals: list[float] = []  # drawn ahead from _rng, in blocks (see _normal)
        self._normal_next = 0
        self.conversions = 0  #: codes produced (diagnostic)
        self._runs = 0
        super().__init__(name)

    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> Vmivme3113aBoard:
        """One board of lanes holding ``boards`` (the same 3113A of B instances built and set up as
        scalar runs build them, in lane order): registers, parameters and noise streams stacked,
        for ``crate`` (a crate of lanes) to install where they were (the section "lanes" below)."""
        adcs = [b for b in boards if type(b) is cls]
        if len(adcs) != len(boards):
            raise NotImplementedError(f"{boards[0].name}: other board types cannot stack into one {cls.__name__}")
        return _stack_3113a_boards(cls, adcs, crate)

    # --- power-up / reset -----------------------------------------------------------------
    def reset(self) -> None:
        super().reset()  # registers to their reset values, a pending request released
        #: per channel: (run ident, conversion index) of the code its word holds
        self._held: list[tuple[int, int] | None] = [None] * CHANNELS
        self._done_before = (0, 0)  # (conversions, scans) of the runs before the current one
        self._seen = (0, 0)  # (conversions, scans) at the previous CSR read
        self._run: _Run | None = None
        self._start_run(None)  # autoscanning, from now

    # --- the sequencer ----------------------------------------------------------------------
    def _start_run(self, limit: int | None) -> None:
        self._fold()
        self._runs += 1
        self._run = _Run(self._runs, self.now_ns, limit)

    def _stop_run(self) -> None:
        self._fold()
        self._run = None

    def _fold(self) -> None:
        """Before the current run is replaced: store the codes of its ended conversions that no
        read has made yet (the words must hold them, not a later net value), and count its
        conversions and scans."""
        if self._run is not None:
            self._materialize()
        self._done_before = self._ended()

    def _materialize(self) -> None:
        for channel in range(CHANNELS):
            self._read_channel(channel)

    def _completed(self, run: _Run | None, now: int) -> int:
        """Conversions of ``run`` ended by ``now``."""
        if run is None:
            return 0
        n = (now - run.start_ns) // self.conversion_time_ns
        return n if run.limit is None or n < run.limit else run.limit

    def _ended(self) -> tuple[int, int]:
        """(conversions, full scans) ended since the reset, up to now."""
        conv, scans = self._done_before
        run = self._run
        if run is None:
            return conv, scans
        n = self._completed(run, self.now_ns)
        return conv + n, scans + n // CHANNELS

    @property
    def mode(self) -> int:
        return (self.regs["CSR"] & _MODE_MASK) >> _MODE_SHIFT

    # --- analog front end ---------------------------------------------------------------
    def input_volts(self, channel: int) -> float:
        """The noiseless voltage at ``channel``'s input pin now (0 V if unwired)."""
        net = self.wiring.get(channel)
        if net is None or self.crate is None:
            return 0.0
        return self.crate.signals.get_analog(net)

    def convert(self, channel: int) -> int:
        """One conversion of ``channel`` now: its offset-binary code (faults, noise, errors)."""
        self.conversions += 1
        stuck = self.fault("stuck_channel")
        if stuck is not None and int(stuck.get("channel", -1)) == channel:
            return int(stuck.get("code", 0)) & CODE_MAX
        v = self.input_volts(channel)
        var = self.noise_rms_v**2
        burst = self.fault("noise_burst")
        if burst is not None:
            chans = burst.get("channels")
            if chans is None or channel in chans:
                var += float(burst.get("rms_v", 0.0)) ** 2
        if var > 0:
            v += math.sqrt(var) * self._normal()
        v = v * (1.0 + self.gain_error[channel]) + self.offset_v[channel]
        return quantize(v, self.input_range)

    def _normal(self) -> float:
        """The next standard normal of the board's noise stream, drawn in blocks of 256: the same
        numbers in the same order as one draw per sample, without a numpy call per sample (a
        tick reads 32 channels)."""
        i = self._normal_next
        if i >= len(self._normals):
            self._normals = self._rng.standard_normal(_NORMAL_BLOCK).tolist()
            i = 0
        self._normal_next = i + 1
        return self._normals[i]

    def noise_state(self, lane: int = 0) -> tuple[Mapping[str, Any], tuple[float, ...]]:
        """The noise stream where it stands: its generator's state and the normals drawn ahead
        and not used yet (of ``lane``, on a board of lanes). Two boards with equal states draw the
        same noise from now on."""
        if self._lanes is not None:
            return self._lanes.noise_state(lane)
        return self._rng.bit_generator.state, tuple(self._normals[self._normal_next:])

    # --- registers ----------------------------------------------------------------------
    def read_CSR(self) -> int:
        conv, scans = self._ended()
        seen_conv, seen_scans = self._seen
        self._seen = (conv, scans)
        value = self.regs["CSR"] & _CSR_STORED
        if conv > seen_conv:
            value |= _NEW_DATA_READY
        if scans > seen_scans:
            value |= _END_OF_SCAN
        return value

    def write_CSR(self, value: int) -> None:
        if value & _SOFTWARE_RESET:
            self.reset()
            return
        old_mode = self.mode
        self.regs["CSR"] = value & _CSR_STORED
        mode = self.mode
        if mode != old_mode:
            if mode == MODE_AUTOSCAN:
                self._start_run(None)
            else:
                self._stop_run()  # the scanning modes wait for START_CONVERT; random ones are not modelled
        if value & _START_CONVERT and mode in (MODE_SCAN_POLL, MODE_SCAN_IRQ):
            run = self._run
            if run is None or run.limit is None or self._completed(run, self.now_ns) >= run.limit:
                self._drop_irq()
                self._start_run(CHANNELS)
                self._schedule_end_of_scan()

    def write_ICR(self, value: int) -> None:
        self.regs["ICR"] = value & 0xFF
        if not value & _ICR_IE:
            self._drop_irq()

    def write_IVR(self, value: int) -> None:
        self.regs["IVR"] = value & 0xFF

    def _resolve_read(self, offset: int, width: Width) -> Any:
        read = super()._resolve_read(offset, width)
        if not DATA_BASE <= offset < DATA_BASE + 2 * CHANNELS or width is not Width.D16 or offset % 2:
            return read
        channel = (offset - DATA_BASE) // 2
        return lambda: self._read_channel(channel)

    def _read_channel(self, channel: int) -> int:
        """CHk: the word of channel k's latest ended conversion, made now if it is newer than
        the one the register holds."""
        run = self._run
        if run is not None:
            n = self._completed(run, self.now_ns)  # conversions 0..n-1 of the run have ended
            if n > channel:
                j = channel + (n - 1 - channel) // CHANNELS * CHANNELS  # its latest conversion
                key = (run.ident, j)
                if self._held[channel] != key:
                    self._held[channel] = key
                    code = self.convert(channel)
                    self.regs[_CH[channel]] = data_word(code, bool(self.regs["CSR"] & _TWOS))
        return self.regs[_CH[channel]]

    # --- interrupts -----------------------------------------------------------------------
    def _schedule_end_of_scan(self) -> None:
        if self.crate is None:
            return
        run = self._run
        assert run is not None
        ident = run.ident
        end = run.start_ns + CHANNELS * self.conversion_time_ns
        self.crate.clock.schedule(end, lambda: self._end_of_scan(ident))

    def _end_of_scan(self, ident: int) -> None:
        """The end of a scanning-mode scan: its 64 codes are made now, so a later read returns
        them and not the nets' values at that read; then MODE 4's interrupt."""
        if self._run is None or self._run.ident != ident:
            return
        self._materialize()
        if self.mode != MODE_SCAN_IRQ:
            return
        icr = self.regs["ICR"]
        level = icr & _ICR_LEVEL
        if icr & _ICR_IE and level:
            self.request_irq(level, self.regs["IVR"])

    def iack(self, level: int) -> int:
        vector = super().iack(level)  # ROAK: the request is released here
        icr = self.regs["ICR"]
        if icr & _ICR_IRAC:
            icr &= ~_ICR_IE
        if icr & _ICR_FAC:
            icr &= ~_ICR_FLAG
        self.regs["ICR"] = icr
        return vector

    def _drop_irq(self) -> None:
        self.release_irq()

    # --- crate hooks ---------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        return {
            "type": self.TYPE,
            "vendor": "VMIC",
            "model": "VMIVME-3113A",
            "document": "docs/boards/vmivme-3113a.md",
            "id": f"0x{BOARD_ID:04X}",
            "channels": CHANNELS,
            "wired": len(self.wiring),
            "input_range": self.input_range,
            "conversion_us": self.conversion_time_ns / 1000,
        }


_CH = tuple(f"CH{k}" for k in range(CHANNELS))


def vmivme3113a_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> Vmivme3113aBoard:
    """Crate-file factory for ``type = "vmivme-3113a"``.

    Keys: ``wiring`` (table channel → net), ``input_range``, ``noise_rms_v``, ``offset_v`` and
    ``gain_error`` (64 numbers each), ``conversion_time_us``. The noise seed is the crate's.
    """
    return Vmivme3113aBoard(
        name,
        wiring=wiring_from_config(cfg, CHANNELS),
        input_range=cfg.get_str("input_range", "bipolar_10v", choices=tuple(RANGES)),
        noise_rms_v=cfg.get_float("noise_rms_v", 0.0, min=0.0, max=10.0),
        offset_v=cfg.floats("offset_v", None, length=CHANNELS) if "offset_v" in cfg else None,
        gain_error=cfg.floats("gain_error", None, length=CHANNELS) if "gain_error" in cfg else None,
        conversion_time_ns=round(cfg.get_float("conversion_time_us", DEFAULT_CONVERSION_TIME_NS / 1000,
                                               min=0.1, max=10_000.0) * 1000),
        seed=ctx.seed,
    )


# --- lanes: B boards of B instances of a rig in one board (batched lockstep, issue #34) ----------
# Vmivme3113aBoard.from_lanes builds an ordinary board and gives it a _Vmi3113aLanes, which holds
# what differs per lane and replaces, once, the hooks that branch on a register value or compute a
# code (convert, _read_channel, write_CSR, write_ICR, _end_of_scan, iack); the scalar code above runs
# unchanged, on the scalar board and on every other path of the board of lanes.
# * The sequencer is every lane's: the lanes make the same bus cycles at the same simulated times
#   (one clock), so the runs, which conversion each word holds, the CSR's status bits and the
#   conversions counter run the scalar code on plain ints. Where a register value decides the
#   sequence (a CSR write's SOFTWARE_RESET, a MODE change, START_CONVERT; the end-of-scan interrupt;
#   ICR.INTERRUPT_ENABLE cleared with a request pending), the live lanes' common answer is taken and
#   a lane that would have done otherwise is ejected (hal.lanes.LaneSet.decide).
# * A conversion runs on (B,) arrays with convert's and quantize's operations in their order (+ - *
#   /, sqrt, floor: the same bits as the scalar floats); the data word's format (CSR.TWOS_COMPLEMENT)
#   is each lane's. A NaN at a lane's input (the scalar quantize's ValueError) or a value math.floor
#   cannot convert (±inf: OverflowError) ejects that lane; the others go on.
# * Noise: each lane keeps its scalar board's generator and block of normals (emulators.adc.LaneNormals)
#   and draws where its scalar board draws: at every conversion when its noise_rms_v > 0, never else
#   (the board has no other noise source: no switching noise couples into it, see docs).
# * Per-lane parameters (--vary): noise_rms_v, offset_v, gain_error.
# Out of scope (NotImplementedError when stacking or converting): armed faults, a pending interrupt,
# boards differing in name, wiring, range, timing or sequencer state (then the instances differ in
# their set-up, not their parameters).


def _stack_3113a_boards(cls: type[Vmivme3113aBoard], boards: Sequence[Vmivme3113aBoard],
                        crate: Backplane) -> Vmivme3113aBoard:
    """:meth:`Vmivme3113aBoard.from_lanes`: one board holding ``boards`` (one per lane, in lane order)."""
    lanes = getattr(crate, "lanes", None)
    if not isinstance(lanes, LaneSet):
        raise ValueError("Vmivme3113aBoard.from_lanes needs a crate of lanes (its .lanes is a hal.lanes.LaneSet)")
    if len(boards) != lanes.size:
        raise ValueError(f"{len(boards)} VMIVME-3113A boards for a crate of {lanes.size} lanes")
    first = boards[0]

    def sequencer(b: Vmivme3113aBoard) -> tuple[object, ...]:
        run = b._run
        return (b._held, b._done_before, b._seen, b._runs,
                None if run is None else (run.ident, run.start_ns, run.limit))

    for b in boards:
        if b.faulted:
            raise NotImplementedError(f"{b.name}: a VMIVME-3113A with a fault armed cannot run in lanes "
                                      "(faults: scalar)")
        if b._irq_level:
            raise NotImplementedError(f"{b.name}: a VMIVME-3113A interrupting cannot be stacked")
        if (b.name, b.wiring, b.input_range, b.conversion_time_ns) != \
                (first.name, first.wiring, first.input_range, first.conversion_time_ns):
            raise NotImplementedError(f"{b.name}: VMIVME-3113As differing in name, wiring, range or timing "
                                      "cannot run in lanes")
        if sequencer(b) != sequencer(first):
            raise NotImplementedError(f"{b.name}: VMIVME-3113As whose sequencers differ cannot run in lanes")
    board = cls(first.name, wiring=first.wiring, input_range=first.input_range,
                conversion_time_ns=first.conversion_time_ns)
    board._stack_regs(boards)
    board._held = list(first._held)
    board._done_before, board._seen, board._runs = first._done_before, first._seen, first._runs
    run = first._run
    board._run = None if run is None else _Run(run.ident, run.start_ns, run.limit)
    board.noise_rms_v = stack([b.noise_rms_v for b in boards])
    board.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(CHANNELS))
    board.gain_error = tuple(stack([b.gain_error[ch] for b in boards]) for ch in range(CHANNELS))
    board.conversions = stack([b.conversions for b in boards])
    fe = _Vmi3113aLanes(board, boards, lanes)
    board._lanes = fe
    # the hooks that branch on register values or compute a code: selected once, here (the scalar
    # board's code runs unchanged on every other path)
    board.convert = fe.convert  # type: ignore[method-assign,assignment]
    board._read_channel = fe.read_channel  # type: ignore[method-assign,assignment]
    board.write_CSR = fe.write_CSR  # type: ignore[method-assign]
    board.write_ICR = fe.write_ICR  # type: ignore[method-assign]
    board._end_of_scan = fe.end_of_scan  # type: ignore[method-assign]
    board.iack = fe.iack  # type: ignore[method-assign]
    return board


class _Vmi3113aLanes(LaneNormals):
    """What a board of lanes holds per lane, and its lane-mode hooks (the section's comment)."""

    def __init__(self, board: Vmivme3113aBoard, boards: Sequence[Vmivme3113aBoard], lanes: LaneSet) -> None:
        super().__init__(boards)
        self.board, self.lanes = board, lanes
        # the scalar expressions of convert, evaluated per lane in Python (the same bits)
        self.sigma = np.array([math.sqrt(b.noise_rms_v**2) for b in boards], dtype=float)
        #: the lanes that draw a normal at each conversion (their scalar boards' var > 0)
        self.draw = self.sigma > 0
        self.all_draw, self.any_draw = bool(self.draw.all()), bool(self.draw.any())
        self.gain1 = tuple(stack([1.0 + b.gain_error[ch] for b in boards]) for ch in range(CHANNELS))
        self.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(CHANNELS))
        self.v0, self.lsb = RANGES[board.input_range]

    # --- a conversion of every lane -------------------------------------------------------
    def convert(self, channel: int) -> np.ndarray:
        """:meth:`Vmivme3113aBoard.convert` of every lane: the offset-binary codes (B,) int64."""
        b = self.board
        if b.faulted:
            raise NotImplementedError(f"{b.name}: a VMIVME-3113A of lanes cannot convert with a fault armed "
                                      "(faults: scalar)")
        b.conversions += 1
        net = b.wiring.get(channel)
        analog = b.crate.signals.analog if b.crate is not None else {}
        with np.errstate(all="ignore"):  # a dead lane's garbage (inf, NaN) must not warn or raise
            v: Any = 0.0 if net is None else analog.get(net, 0.0)
            if self.all_draw:
                v = v + self.sigma * self._normals_all()
            elif self.any_draw:
                v = np.where(self.draw, v + self.sigma * self._normals_some(self.draw), v)
            if not isinstance(v, np.ndarray):
                v = np.full(self.n, v)
            v = v * self.gain1[channel] + self.offset_v[channel]
            x = (v - self.v0) / self.lsb + 0.5
            ok = np.isfinite(x)
            if not ok.all():
                nan = v != v
                self.lanes.eject(nan, f"{b.name}: ADC input is NaN (channel {channel})")
                self.lanes.eject(~ok & ~nan, f"{b.name}: ADC input out of the float range (channel {channel})")
                x = np.where(ok, x, 0.0)
            code = np.floor(x)
        np.maximum(code, 0.0, out=code)
        np.minimum(code, float(CODE_MAX), out=code)
        return code.astype(np.int64)

    def read_channel(self, channel: int) -> Any:
        """:meth:`Vmivme3113aBoard._read_channel` of every lane (which conversion a word holds is
        every lane's; the code and its format are each lane's)."""
        b = self.board
        run = b._run
        if run is not None:
            n = b._completed(run, b.now_ns)
            if n > channel:
                j = channel + (n - 1 - channel) // CHANNELS * CHANNELS
                key = (run.ident, j)
                if b._held[channel] != key:
                    b._held[channel] = key
                    code = b.convert(channel)
                    b.regs[_CH[channel]] = _lane_data_word(code, b.regs["CSR"] & _TWOS)
        return b.regs[_CH[channel]]

    # --- the register values that decide the sequence: one answer for every lane ----------
    def write_CSR(self, value: Any) -> None:
        """:meth:`Vmivme3113aBoard.write_CSR` of every lane (``value`` a lane value)."""
        b, lanes = self.board, self.lanes
        if lanes.decide((value & _SOFTWARE_RESET) != 0, f"{b.name}: CSR.SOFTWARE_RESET written in some lanes only"):
            b.reset()
            return
        old_mode = b.regs["CSR"] & _MODE_MASK
        b.regs["CSR"] = value & _CSR_STORED
        mode = b.regs["CSR"] & _MODE_MASK
        if lanes.decide(mode != old_mode, f"{b.name}: MODE changed in some lanes only"):
            if lanes.decide(mode == MODE_AUTOSCAN << _MODE_SHIFT, f"{b.name}: autoscanning in some lanes only"):
                b._start_run(None)
            else:
                b._stop_run()
        scanning = (mode == MODE_SCAN_POLL << _MODE_SHIFT) | (mode == MODE_SCAN_IRQ << _MODE_SHIFT)
        if lanes.decide(((value & _START_CONVERT) != 0) & scanning, f"{b.name}: scan started in some lanes only"):
            run = b._run
            if run is None or run.limit is None or b._completed(run, b.now_ns) >= run.limit:
                b._drop_irq()
                b._start_run(CHANNELS)
                b._schedule_end_of_scan()

    def write_ICR(self, value: Any) -> None:
        """:meth:`Vmivme3113aBoard.write_ICR` of every lane: with no request pending, releasing it
        changes nothing, so nothing is decided."""
        b = self.board
        b.regs["ICR"] = value & 0xFF
        if b._irq_level and self.lanes.decide((value & _ICR_IE) == 0,
                                              f"{b.name}: interrupt released in some lanes only"):
            b._drop_irq()

    def end_of_scan(self, ident: int) -> None:
        """:meth:`Vmivme3113aBoard._end_of_scan` of every lane."""
        b, lanes = self.board, self.lanes
        if b._run is None or b._run.ident != ident:
            return
        b._materialize()
        regs = b.regs
        icr = regs["ICR"]
        level = icr & _ICR_LEVEL
        request = ((regs["CSR"] & _MODE_MASK) == MODE_SCAN_IRQ << _MODE_SHIFT) & ((icr & _ICR_IE) != 0) & (level != 0)
        if lanes.decide(request, f"{b.name}: end-of-scan interrupt in some lanes only"):
            b.request_irq(common_value(lanes, level, f"{b.name}: ICR.LEVEL differs"),
                          common_value(lanes, regs["IVR"], f"{b.name}: IVR differs"))

    def iack(self, level: int) -> int:
        """:meth:`Vmivme3113aBoard.iack` of every lane: the auto-clears as bit arithmetic (the
        INTR_AUTO_CLEAR bit is one below INTERRUPT_ENABLE, FLAG_AUTO_CLEAR one below FLAG)."""
        b = self.board
        vector = RegisterBoard.iack(b, level)  # ROAK: the request is released here
        icr = b.regs["ICR"]
        icr = icr & ~((icr & _ICR_IRAC) << 1)
        b.regs["ICR"] = icr & ~((icr & _ICR_FAC) << 1)
        return vector


def _lane_data_word(code: Any, twos: Any) -> Any:
    """:func:`data_word` of codes (B,) in each lane's format (``twos``: CSR & TWOS_COMPLEMENT, a
    lane value)."""
    tc = code ^ 0x800
    tc = tc | ((tc >> 11) & 1) * 0xF000  # bits 15:12 = the inverted MSB, as data_word's sign extension
    if not isinstance(twos, np.ndarray):
        return tc if twos else code
    return np.where(twos != 0, tc, code)
