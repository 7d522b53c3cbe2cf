"""Register-level emulator of the VMIC VMIVME-4116 (8 channels, 16 bit, ±10 V analog output),
written from ``docs/boards/vmivme4116.md``.

A second reading of the board, independent of the driver (:mod:`hal.adc_dac`, which it does not
import): its register map, bits and code → volts are its own literal Python, written from the
doc's register table and coding. Tests check this map and the driver's, each against the doc.

Behaviour (see the doc):

* Eight write-only channel latches (+0x00..+0x0E) and a CSR (+0x10); 0x12..0x1F, D8 and D32 end
  in BERR; a read of a channel register completes with 0xFFFF (never the code).
* Power-up / reset: every output 0 V and disconnected from P3 (the wired net reads 0 V), every
  latch at the 0 V code, CSR 0x0000 (fail LED on).
* ``update="synchronized"`` (the board's jumper): a channel write loads its holding latch; CSR
  bit 9 (START_CONVERT) copies all eight to the converters at once. ``"immediate"``: a channel
  write reaches its converter at once; START_CONVERT does nothing.
* CSR bit 8 (AO_P3) connects the converters to the P3 pins (the wired nets).
* Output ``v = ideal(code)·(1 + gain_error) + offset_v``, clipped at ±``rail_v``; settling
  first-order, τ = settling time / ln 131072 (½ LSB of a full-scale step at the settling time);
  the net gets the final value one settling time after the update (a newer update supersedes).

Fault: ``dead_channel(channel, volts=0.0)`` — the output pin sits at ``volts`` whatever is written.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`VmiVme4116Board.from_lanes` stacks B boards into
one whose holding latches, converter codes, offset/gain errors, rails and output volts are lane
values; the CSR (the outputs' P3 switch, the update strobe) and so the settling events are the
same in every lane (one clock: a CSR word that differs ejects the lanes of the minority).
Injected faults are not carried into lanes (those runs go scalar).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from functools import partial
from typing import Any, ClassVar

import numpy as np

from emulators.adc import common_value, per_channel, wiring_from_config
from emulators.board import Backplane, RegisterBoard
from emulators.board_factory import BuildContext
from hal.config import ConfigTable
from hal.lanes import LaneSet, LaneValue, stack
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the board, as docs/boards/vmivme4116.md states it ------------------------------------------
CHANNELS = 8
FULL_SCALE_V = 10.0
LSB_V = 20.0 / 65536  #: 305.17578125 µV
DEFAULT_SETTLING_NS = 10_000  #: 10 µs to ½ LSB
CHAN_READ_VALUE = 0xFFFF  #: what a read of a write-only channel register answers (doc: undefined)

REGMAP = RegisterMap(
    "vmivme-4116",
    0x20,  # chan[8] at 0x00..0x0E, csr at 0x10, unused[7] to 0x1F
    AddressSpace.A16,
    (
        *(Register(f"CHAN{n}", 2 * n, Width.D16, Access.WO, (Field("CODE", 0, 16),), reset=0x8000)
          for n in range(CHANNELS)),
        Register("CSR", 0x10, Width.D16, Access.RW,
                 (Field("LED_OFF", 14), Field("AOTESTBS", 13), Field("AINTESTBS", 12), Field("TESTBUS", 11),
                  Field("START_CONVERT", 9), Field("AO_P3", 8)), reset=0x0000),
    ),
    doc="emulated VMIC VMIVME-4116 8-channel 16-bit analog output (docs/boards/vmivme4116.md)",
)

LED_OFF = 1 << 14
START_CONVERT = 1 << 9
AO_P3 = 1 << 8
#: the CSR bits that hold what was written (START_CONVERT is a strobe and reads 0; the bits no
#: source names read 0)
_CSR_STORED = LED_OFF | (1 << 13) | (1 << 12) | (1 << 11) | AO_P3

UPDATE_MODES = ("synchronized", "immediate")
CODINGS = ("offset_binary", "twos_complement")


def ideal_volts(code: int, coding: str = "offset_binary") -> float:
    """Ideal output of a 16-bit ``code``: offset binary 0x8000 = 0 V (0x0000 −10 V, 0xFFFF
    +9.999695 V); two's complement 0x0000 = 0 V, 0x8000 = −10 V, 0x7FFF = +9.999695 V."""
    signed = code - 0x10000 if code & 0x8000 else code  # two's complement value
    offset = code - 0x8000
    return (signed if coding == "twos_complement" else offset) * LSB_V


def ideal_volts_lanes(code: LaneValue, coding: str = "offset_binary") -> LaneValue:
    """:func:`ideal_volts` of a code per lane (an int, or an int64 array): the same integer
    value times the LSB, so the same volts bit for bit. The sign of a two's complement code is
    taken without a branch (bit 15 set: less 0x10000)."""
    if coding == "twos_complement":
        return (code - ((code & 0x8000) << 1)) * LSB_V
    return (code - 0x8000) * LSB_V


class VmiVme4116Board(RegisterBoard):
    """Emulated VMIVME-4116.

    Args:
        name: board name in the crate.
        wiring: channel → analog net the output (P3 pin) drives.
        update: the update jumper, ``"synchronized"`` or ``"immediate"``.
        coding: ``"offset_binary"`` or ``"twos_complement"``.
        offset_v, gain_error: per-channel output errors (8 values each).
        settling_time_ns: from the update to the final value on the net.
        rail_v: output stage saturation (± volts).
    """

    TYPE = "vmivme-4116"
    VENDOR = "VMIC"
    MODEL = "VMIVME-4116"
    DOCUMENT = "docs/boards/vmivme4116.md"
    REGMAP = REGMAP
    FAULTS: ClassVar[dict[str, str]] = {
        "dead_channel": "channel=N[, volts=V]: output N stuck at V (default 0 V) whatever is written",
    }
    _lanes: LaneSet  #: in lane mode only (from_lanes): the crate's lanes

    def __init__(
        self,
        name: str,
        *,
        wiring: Mapping[int, str] | None = None,
        update: str = "synchronized",
        coding: str = "offset_binary",
        offset_v: Sequence[float] | None = None,
        gain_error: Sequence[float] | None = None,
        settling_time_ns: int = DEFAULT_SETTLING_NS,
        rail_v: float = 10.5,
    ) -> None:
        if update not in UPDATE_MODES:
            raise ValueError(f"{name}: update {update!r} is not one of {', '.join(UPDATE_MODES)}")
        if coding not in CODINGS:
            raise ValueError(f"{name}: coding {coding!r} is not one of {', '.join(CODINGS)}")
        self.wiring: dict[int, str] = {}
        for ch, net in (wiring or {}).items():
            if not 0 <= int(ch) < CHANNELS:
                raise ValueError(f"{name}: wiring channel {ch} is not 0..{CHANNELS - 1}")
            self.wiring[int(ch)] = str(net)
        self.synchronized = update == "synchronized"
        self.coding = coding
        self.offset_v = per_channel(name, "offset_v", offset_v, CHANNELS)
        self.gain_error = per_channel(name, "gain_error", gain_error, CHANNELS)
        if settling_time_ns < 0:
            raise ValueError(f"{name}: settling_time_ns must be >= 0")
        self.settling_time_ns = int(settling_time_ns)
        self.tau_ns = self.settling_time_ns / math.log(131072)  # ½ LSB of a 20 V step is 1/131072 of it
        self.rail_v = float(rail_v)
        self.zero_code = 0x0000 if coding == "twos_complement" else 0x8000
        self.holding: list[int] = []  #: the holding latches
        self.converter: list[int] = []  #: the codes in the converters (what drives the outputs)
        self._step: list[tuple[int, float, float]] = []  # per channel: (update ns, volts then, final volts)
        self._gen = [0] * CHANNELS
        self.updates = 0  #: number of converter updates (diagnostic)
        super().__init__(name)

    # --- power-up / reset ---------------------------------------------------------------
    def reset(self) -> None:
        super().reset()
        self.holding = [self.zero_code] * CHANNELS
        self.converter = [self.zero_code] * CHANNELS
        self._step = [(self.now_ns, v, v) for v in (self._analog(ch, self.zero_code) for ch in range(CHANNELS))]
        self._gen = [g + 1 for g in self._gen]
        self._drive_all()

    def attach(self, crate) -> None:
        super().attach(crate)
        self._step = [(self.now_ns, v, v) for _, _, v in self._step]
        self._drive_all()

    # --- state a test reads -----------------------------------------------------------------
    @property
    def connected(self) -> bool:
        """The outputs are on the P3 connector (CSR.AO_P3)."""
        return bool(self.regs["CSR"] & AO_P3)

    @property
    def fail_led_on(self) -> bool:
        return not self.regs["CSR"] & LED_OFF

    # --- analog output ------------------------------------------------------------------
    def _analog(self, ch: int, code: int) -> float:
        v = ideal_volts(code, self.coding) * (1.0 + self.gain_error[ch]) + self.offset_v[ch]
        return min(max(v, -self.rail_v), self.rail_v)

    def _dead_volts(self, ch: int) -> float | None:
        if not self.faulted:
            return None
        f = self.fault("dead_channel")
        if f is not None and int(f.get("channel", -1)) == ch:
            return float(f.get("volts", 0.0))
        return None

    def converter_volts(self, channel: int, t_ns: int | None = None) -> float:
        """The converter's own (settling) output at ``t_ns`` (default now), before the P3 switch."""
        t = self.now_ns if t_ns is None else t_ns
        t0, v_start, v_final = self._step[channel]
        if self.tau_ns <= 0 or t - t0 >= self.settling_time_ns:
            return v_final
        return v_final + (v_start - v_final) * math.exp(-(t - t0) / self.tau_ns)

    def output_volts(self, channel: int, t_ns: int | None = None) -> float:
        """The voltage at P3 pin ``channel``: 0 V while disconnected, else the converter's."""
        dead = self._dead_volts(channel)
        if dead is not None:
            return dead
        if not self.connected:
            return 0.0
        return self.converter_volts(channel, t_ns)

    def _drive(self, ch: int) -> None:
        """Put the settled (or dead, or disconnected) output of ``ch`` on its net."""
        net = self.wiring.get(ch)
        if net is None or self.crate is None:
            return
        dead = self._dead_volts(ch)
        if dead is not None:
            v = dead
        elif not self.connected:
            v = 0.0  # nothing drives the amplifier's command input
        else:
            v = self._step[ch][2]
        self.crate.signals.set_analog(net, v)

    def _drive_all(self) -> None:
        for ch in range(CHANNELS):
            self._drive(ch)

    def _fault_changed(self, name: str) -> None:
        self._drive_all()

    def _convert(self, channels: Sequence[int]) -> None:
        """Load the given channels' holding latches into their converters, now."""
        now = self.now_ns
        for ch in channels:
            v_now = self.converter_volts(ch, now)
            code = self.holding[ch]
            self.converter[ch] = code
            self._step[ch] = (now, v_now, self._analog(ch, code))
            self._gen[ch] += 1
            gen = self._gen[ch]
            if self.settling_time_ns == 0 or self.crate is None:
                self._drive(ch)
            else:
                self.crate.clock.schedule_in(self.settling_time_ns, partial(self._settled, ch, gen))
        self.updates += 1

    def _settled(self, ch: int, gen: int) -> None:
        if gen == self._gen[ch]:
            self._drive(ch)

    # --- registers ----------------------------------------------------------------------
    def _resolve_read(self, offset: int, width: Width) -> Callable[[], int]:
        # The channel registers are write-only, yet a D16 read of them completes (both EPICS
        # drivers find the board by reading its first word): it answers, with no data.
        reg = self.REGMAP.containing(offset)
        if reg is not None and reg.name.startswith("CHAN") and width is Width.D16 and offset == reg.offset:
            return lambda: CHAN_READ_VALUE
        return super()._resolve_read(offset, width)

    def write_CSR(self, value: int) -> None:
        was_connected = self.connected
        self.regs["CSR"] = value & _CSR_STORED
        if value & START_CONVERT and self.synchronized:
            self._convert(range(CHANNELS))
        if self.connected != was_connected:
            self._drive_all()

    def describe(self) -> dict[str, Any]:
        return {
            "type": self.TYPE,
            "vendor": self.VENDOR,
            "model": self.MODEL,
            "document": self.DOCUMENT,
            "channels": CHANNELS,
            "wired": len(self.wiring),
            "update": "synchronized" if self.synchronized else "immediate",
            "coding": self.coding,
            "outputs": "connected" if self.connected else "disconnected",
        }

    # --- lanes (batched lockstep, hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Any], crate: Any) -> VmiVme4116Board:
        """One board in lane mode holding the B scalar ``boards`` (lane order), for the lane
        crate ``crate`` (which installs it). The holding latches, converter codes, offset/gain
        errors, rails and output volts become lane values. The jumpers (update, coding), the
        wiring, the settling time, the CSR and the update history must be the same in every lane
        (lockstep gives the last two: the same set-up program; ``Crate.from_lanes`` stacks crates
        with no event queued, so no output is settling then). Makes no bus cycle and drives no
        net (``Signals.from_lanes`` stacked them)."""
        first = boards[0]
        for b in boards:
            if type(b) is not cls:
                raise NotImplementedError(f"{first.name}: a {type(b).__name__} cannot be a lane of a {cls.__name__}")
            if b.faulted:
                raise NotImplementedError(f"{b.name}: a board with an injected fault runs scalar")
            if (b.wiring, b.settling_time_ns, b.synchronized, b.coding) != (
                    first.wiring, first.settling_time_ns, first.synchronized, first.coding):
                raise NotImplementedError(f"{first.name}: the lanes' boards differ in wiring, settling time or jumpers")
            if b.regs["CSR"] != first.regs["CSR"]:
                raise NotImplementedError(f"{first.name}: the lanes' boards differ in their CSR (outputs on P3)")
            if (b._gen, [s[0] for s in b._step]) != (first._gen, [s[0] for s in first._step]):
                raise NotImplementedError(f"{first.name}: the lanes' boards were updated at different times")
        obj = cls(first.name, wiring=first.wiring, update="synchronized" if first.synchronized else "immediate",
                  coding=first.coding, settling_time_ns=first.settling_time_ns)
        obj.offset_v = tuple(stack([b.offset_v[ch] for b in boards]) for ch in range(CHANNELS))
        obj.gain_error = tuple(stack([b.gain_error[ch] for b in boards]) for ch in range(CHANNELS))
        obj.rail_v = stack([b.rail_v for b in boards])
        obj._stack_regs(boards)
        obj.holding = [stack([b.holding[ch] for b in boards]) for ch in range(CHANNELS)]
        obj.converter = [stack([b.converter[ch] for b in boards]) for ch in range(CHANNELS)]
        obj._step = [(first._step[ch][0], stack([b._step[ch][1] for b in boards]),
                      stack([b._step[ch][2] for b in boards])) for ch in range(CHANNELS)]
        obj._gen = list(first._gen)
        obj.updates = stack([b.updates for b in boards])
        obj._lanes = crate.lanes
        # the channel writers, _convert, converter_volts and _drive run as they are on lane
        # values (the CSR, the times and the settling generations are every lane's)
        for name in ("attach", "_analog", "write_CSR", "inject"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        return obj

    def _lane_attach(self, crate: Backplane) -> None:
        RegisterBoard.attach(self, crate)  # the steps and the nets are the stacked scalar ones

    def _lane_analog(self, ch: int, code: LaneValue) -> LaneValue:
        v = ideal_volts_lanes(code, self.coding) * (1.0 + self.gain_error[ch]) + self.offset_v[ch]
        rail = self.rail_v
        if not isinstance(v, np.ndarray) and not isinstance(rail, np.ndarray):
            return min(max(v, -rail), rail)
        v = np.where(-rail > v, -rail, v)  # max(v, -rail): a NaN stays, as max() leaves it
        return np.where(rail < v, rail, v)  # min(·, rail)

    def _lane_write_CSR(self, value: LaneValue) -> None:
        # the P3 switch and the strobe are every lane's (one clock for the settling events): a
        # CSR word that differs between lanes takes the majority's, and ejects the others
        VmiVme4116Board.write_CSR(self, common_value(self._lanes, value, f"{self.name}: a CSR write that "
                                                     "differs between lanes (outputs on P3, the update strobe)"))

    def _lane_inject(self, name: str, **params: Any) -> None:
        raise NotImplementedError(f"{self.name}: faults are not injected into lanes (such runs go scalar)")


def _chan_writer(ch: int):
    def write(self: VmiVme4116Board, value: int) -> None:
        self.holding[ch] = value & 0xFFFF
        if not self.synchronized:
            self._convert((ch,))

    write.__name__ = f"write_CHAN{ch}"
    return write


for _ch in range(CHANNELS):  # write_CHAN0..write_CHAN7
    setattr(VmiVme4116Board, f"write_CHAN{_ch}", _chan_writer(_ch))


def vmivme4116_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> VmiVme4116Board:
    """Crate-file factory for ``type = "vmivme-4116"``.

    Keys: ``wiring`` (table channel → net), ``update`` (``"synchronized"``/``"immediate"``),
    ``coding`` (``"offset_binary"``/``"twos_complement"``), ``offset_v`` and ``gain_error``
    (8 numbers each), ``settling_time_us``.
    """
    return VmiVme4116Board(
        name,
        wiring=wiring_from_config(cfg, CHANNELS),
        update=cfg.get_str("update", "synchronized", choices=UPDATE_MODES),
        coding=cfg.get_str("coding", "offset_binary", choices=CODINGS),
        offset_v=cfg.floats("offset_v", None, length=CHANNELS) if "offset_v" in cfg else None,
        gain_error=cfg.floats("gain_error", None, length=CHANNELS) if "gain_error" in cfg else None,
        settling_time_ns=round(cfg.get_float("settling_time_us", DEFAULT_SETTLING_NS / 1000, min=0.0, max=10_000.0)
                               * 1000),
    )
