"""Driver of the VMIC VMIVME-4116, 8 channels of 16-bit ±10 V analog output
(register map :mod:`hal.adc_dac.vmivme4116_regs`; spec ``docs/boards/vmivme4116.md``).

The same interface as the reference DAC's :class:`hal.adc_dac.dac.DacDriver` (volts at the API,
calibration applied, one update for all channels written by :meth:`VmiVme4116Driver.write_many`,
``clamp``), on a board with fewer registers:

* no ID register — the probe reads the CSR (:func:`probe_vmivme4116`);
* no readback of the outputs (the channel registers are write-only) —
  :meth:`VmiVme4116Driver.read_back_counts` reads the CSR, so a board that no longer answers
  raises, then returns the code this driver last saw the board accept for that output;
* one update strobe for all channels (CSR.START_CONVERT), no per-channel strobe;
* outputs disconnected from the P3 connector at power-up: opening the driver writes the 0 V code
  to every channel, strobes it with the outputs off P3, waits the 10 µs settling time and only
  then connects the outputs, so the amplifiers' first command is 0 V whatever the latches held.

Example::

    dac = VmiVme4116Driver(crate, 0x7000)
    dac.write_many({0: 1.0, 1: -1.0})    # one synchronized update
    dac.zero()                           # every output to 0 V (the stop path)

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`VmiVme4116Driver.from_lanes` stacks B drivers
(one per instance) into one on a bus of lanes. Its :meth:`~VmiVme4116Driver.write_many` takes volts
per lane (a float, or a ``(B,)`` array) and loads codes per lane, converted with the same float
math as one driver's (:func:`vmi4116_volts_to_codes`, the array form of
:func:`vmi4116_volts_to_code`) and each lane's calibration; a command one instance's driver would
refuse (NaN, or out of range without ``clamp``) ejects that lane instead of raising.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from typing import Any, Literal

import numpy as np

from hal.adc_dac.calibration import Calibration
from hal.adc_dac.dac import DacRangeError, DacWriteResult, lane_codes
from hal.adc_dac.vmivme4116_regs import VMI4116_CHANNELS, VMI4116_REGMAP
from hal.board_types import ProbeReading
from hal.lanes import LaneSet, LaneValue, stack
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import VmeError
from hal.vme.window import BoardWindow

Coding = Literal["offset_binary", "twos_complement"]
CODINGS: tuple[Coding, ...] = ("offset_binary", "twos_complement")

VMI4116_FULL_SCALE_V = 10.0
VMI4116_LSB_V = 2 * VMI4116_FULL_SCALE_V / 65536  #: 305.17578125 µV
VMI4116_V_MIN = -VMI4116_FULL_SCALE_V  #: volts of offset-binary code 0x0000
VMI4116_V_MAX = VMI4116_FULL_SCALE_V - VMI4116_LSB_V  #: volts of code 0xFFFF (+9.999695 V)
_CODE_MAX = 0xFFFF
_SIGN = 0x8000  #: offset binary ↔ two's complement: bit 15 inverted

_CSR = VMI4116_REGMAP["CSR"]
#: the CSR this driver keeps: fail LED off, outputs on P3 (what both EPICS drivers write at init)
_CSR_RUN = _CSR.pack(LED_OFF=1, AO_P3=1)
#: the same with the update strobe: every holding latch to its output
_CSR_UPDATE = _CSR_RUN | _CSR.field("START_CONVERT").mask
#: the power-up state: outputs off P3, fail LED on
_CSR_OFF = 0x0000
#: the bring-up's strobe: every latch to its converter while the outputs stay off P3
_CSR_UPDATE_OFF = _CSR.pack(START_CONVERT=1)
VMI4116_SETTLING_S = 10e-6  #: to ½ LSB after an update (the product sheet)
_CHAN = tuple(f"CHAN{i}" for i in range(VMI4116_CHANNELS))


class Vmi4116RangeError(DacRangeError):
    """A command outside the VMIVME-4116's −10 V … +9.999695 V (a :class:`DacRangeError`)."""

    def __init__(self, channel: int, volts: float, command_v: float) -> None:
        super().__init__(channel, volts, command_v)
        cal = "" if command_v == volts else f" (calibrated command {command_v:+.5f} V)"
        self.args = (
            f"VMIVME-4116 channel {channel}: {volts:+.5f} V{cal} is outside the output range "
            f"{VMI4116_V_MIN:+.5f}..{VMI4116_V_MAX:+.5f} V; limit the command upstream or open the driver with "
            "clamp=True",
        )


def vmi4116_volts_to_code(volts: float, coding: Coding = "offset_binary") -> tuple[int, bool]:
    """Output volts → (16-bit code in ``coding``, clipped). ``clipped`` when ``volts`` lies more
    than ½ LSB outside −10 V … +9.999695 V (the code is then the nearer end code); NaN raises."""
    if math.isnan(volts):
        raise ValueError("DAC command is NaN")
    code = math.floor((volts - VMI4116_V_MIN) / VMI4116_LSB_V + 0.5)
    clipped = not 0 <= code <= _CODE_MAX
    code = min(max(code, 0), _CODE_MAX)
    return (code ^ _SIGN if coding == "twos_complement" else code), clipped


def vmi4116_volts_to_codes(volts: Any, coding: Coding = "offset_binary") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Array form of :func:`vmi4116_volts_to_code`, element by element with the same float math
    (so the same codes, bit for bit): ``(codes, clipped, invalid)`` — int64, bool and bool arrays
    of ``volts``' shape. ``invalid`` marks the elements the scalar form rejects (NaN: ``ValueError``;
    ±inf, or a value whose code overflows a float: ``OverflowError``); they get the 0 V code of
    ``coding``, unclipped."""
    v = np.asarray(volts, dtype=float)
    with np.errstate(invalid="ignore", over="ignore"):
        code = np.floor((v - VMI4116_V_MIN) / VMI4116_LSB_V + 0.5)
    invalid = ~np.isfinite(code)
    code = np.where(invalid, _SIGN, code)  # offset binary's 0 V code
    low, high = code < 0, code > _CODE_MAX
    codes = np.where(low, 0, np.where(high, _CODE_MAX, code)).astype(np.int64)
    return (codes ^ _SIGN if coding == "twos_complement" else codes), low | high, invalid


def vmi4116_code_to_volts(code: int, coding: Coding = "offset_binary") -> float:
    """16-bit code in ``coding`` → ideal output volts."""
    if not 0 <= code <= _CODE_MAX:
        raise ValueError(f"DAC code {code} is outside 0..0xFFFF")
    if coding == "twos_complement":
        code ^= _SIGN
    return VMI4116_V_MIN + code * VMI4116_LSB_V


def probe_vmivme4116(bus: VmeBus, base: int, space: SpaceLike = "A16") -> ProbeReading:
    """The board type's probe (``hal.board_types``): read the CSR of a VMIVME-4116 at ``base``;
    nothing is written. The board has no ID register, so this proves only that something answers
    a D16 read at +0x10 (``ok`` False, with the bus error, if nothing does)."""
    try:
        csr = BoardWindow(bus, base, VMI4116_REGMAP, space).read("CSR")
    except VmeError as e:
        return ProbeReading(False, f"{type(e).__name__}: {e}")
    return ProbeReading(True, f"no ID register (VMIVME-4116); CSR 0x{csr:04X}")


class VmiVme4116Driver:
    """Driver of one VMIVME-4116.

    Args:
        bus: the VME bus.
        base: board base address (a 32-byte boundary).
        space: address space or AM of the board window.
        calibration: per-channel offset/gain (8 channels) of the outputs; identity if None.
        clamp: clamp out-of-range commands (and report them) instead of raising.
        coding: the board's data coding setting, ``"offset_binary"`` or ``"twos_complement"``.
        synchronized: the board's update jumper is set for synchronized update (the default, the
            arm's); with ``False`` (immediate update) a write reaches its output at once, which is
            what :meth:`read_back_counts` then records.

    Raises:
        BusError: nothing answers the probe.
    """

    CHANNELS = VMI4116_CHANNELS
    # in lane mode only (from_lanes): the lanes, and each channel's calibration per lane
    _lanes: LaneSet
    _cal_offset_v: tuple[LaneValue, ...]
    _cal_gain: tuple[LaneValue, ...]

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        calibration: Calibration | None = None,
        clamp: bool = False,
        coding: Coding = "offset_binary",
        synchronized: bool = True,
    ) -> None:
        if coding not in CODINGS:
            raise ValueError(f"VMIVME-4116 coding {coding!r}: expected one of {', '.join(CODINGS)}")
        self.bus = bus
        self.coding: Coding = coding
        self.synchronized = synchronized
        self.calibration = calibration or Calibration.identity(VMI4116_CHANNELS)
        if self.calibration.channels != VMI4116_CHANNELS:
            raise ValueError(f"VMIVME-4116 calibration has {self.calibration.channels} channels, the board has 8")
        self.clamp = clamp
        self.clamp_events = 0  #: number of channel writes that were clamped (clamp=True)
        self.win = BoardWindow(bus, base, VMI4116_REGMAP, space)
        self.zero_code = vmi4116_volts_to_code(0.0, coding)[0]  #: the 0 V code in this coding
        self._holding = [self.zero_code] * VMI4116_CHANNELS
        self._output = [self.zero_code] * VMI4116_CHANNELS
        self.win.read("CSR")  # the probe: BusError when nothing is there
        self._bring_up()

    def _bring_up(self) -> None:
        # The amplifiers must see 0 V first, whatever the latches held and whether or not the
        # outputs were connected: load the 0 V code, strobe it with the outputs off P3, let the
        # converters settle, and only then connect (and put the fail LED out).
        for ch in range(VMI4116_CHANNELS):
            self._load(ch, self.zero_code)
        self.win.write("CSR", _CSR_UPDATE_OFF)
        self._output = list(self._holding)
        self.bus.delay(VMI4116_SETTLING_S)
        self.win.write("CSR", _CSR_RUN)

    # --- conversion -----------------------------------------------------------------------
    def code_for(self, channel: int, volts: float) -> tuple[int, bool]:
        """The code that makes output ``channel`` produce ``volts`` (calibration applied) and
        whether it had to be clamped. Raises :class:`Vmi4116RangeError` unless ``clamp``."""
        self._check_channel(channel)
        command = self.calibration.correct(channel, float(volts))
        code, clipped = vmi4116_volts_to_code(command, self.coding)
        if clipped and not self.clamp:
            raise Vmi4116RangeError(channel, float(volts), command)
        return code, clipped

    # --- writes -----------------------------------------------------------------------------
    def write_volts(self, channel: int, volts: float, update: bool = True) -> DacWriteResult:
        """Load ``volts`` into ``channel``; update the outputs if ``update``."""
        return self.write_many({channel: volts}, update=update)

    def write_many(self, commands: Mapping[int, float], update: bool = True) -> DacWriteResult:
        """Load several channels, then (if ``update``) move them all to the outputs with one
        strobe. Every command is checked before any register is written."""
        codes: dict[int, int] = {}
        clamped: list[int] = []
        for ch, v in commands.items():
            codes[ch], c = self.code_for(ch, v)
            if c:
                clamped.append(ch)
        for ch, code in codes.items():
            self._load(ch, code)
        if update and codes:
            self.update()
        self.clamp_events += len(clamped)
        return DacWriteResult(codes, tuple(clamped), update and bool(codes))

    def write_counts(self, channel: int, code: int, update: bool = True) -> None:
        """Load a raw 16-bit code (in the board's coding; no calibration)."""
        self._check_channel(channel)
        if not 0 <= code <= _CODE_MAX:
            raise ValueError(f"DAC code {code} is outside 0..0xFFFF")
        self._load(channel, code)
        if update:
            self.update()

    def update(self, channels: Iterable[int] | None = None) -> None:
        """CSR.START_CONVERT: every holding latch to its output at once. The board has no
        per-channel strobe; ``channels`` is accepted for the reference DAC's interface and
        checked, and every channel is updated (an unchanged latch keeps its output)."""
        for ch in channels or ():
            self._check_channel(ch)
        self.win.write("CSR", _CSR_UPDATE)
        self._output = list(self._holding)

    def zero(self) -> None:
        """Every output to 0 V: the 0 V code (no calibration) to all eight channels, one strobe,
        the outputs connected. The stop path and the bring-up."""
        for ch in range(VMI4116_CHANNELS):
            self._load(ch, self.zero_code)
        self.update()

    def reset(self) -> None:
        """The board has no reset register: :meth:`zero`."""
        self.zero()

    def disconnect(self) -> None:
        """Outputs off the P3 connector, fail LED on: the board's power-up state."""
        self.win.write("CSR", _CSR_OFF)

    # --- status -----------------------------------------------------------------------------
    def read_csr(self) -> int:
        return self.win.read("CSR")

    def read_back_counts(self, channel: int) -> int:
        """The code driving output ``channel``, as far as the driver knows it: the board cannot
        read its outputs back. Reads the CSR first, so a board that stopped answering raises
        ``BusError``; then returns the code last written to the channel and updated, each write
        having ended with DTACK (docs/boards/vmivme4116.md, open point 7)."""
        self._check_channel(channel)
        self.win.read("CSR")
        return self._output[channel]

    def _load(self, channel: int, code: int) -> None:
        self.win.write(_CHAN[channel], code)
        self._holding[channel] = code
        if not self.synchronized:
            self._output[channel] = code

    @staticmethod
    def _check_channel(channel: int) -> None:
        if not 0 <= channel < VMI4116_CHANNELS:
            raise ValueError(f"DAC channel {channel} is not 0..{VMI4116_CHANNELS - 1}")

    # --- lanes (batched lockstep, hal.lanes) -------------------------------------------------
    @classmethod
    def from_lanes(cls, drivers: Sequence[VmiVme4116Driver], bus: VmeBus) -> VmiVme4116Driver:
        """One driver in lane mode for the B scalar ``drivers`` (lane order, each opened on its
        instance's crate) on ``bus``, the crate of their lanes: the same board (base, space),
        ``clamp``, coding and update jumper in every lane; each lane keeps its calibration, its
        clamp count and the codes its driver last loaded and updated. No bus cycle (the bring-up
        was made by each scalar driver)."""
        first = drivers[0]
        if not isinstance(bus.lanes, LaneSet):
            raise ValueError("a VMIVME-4116 driver in lanes needs a bus of lanes (bus.lanes)")
        key = (first.win.base, first.win.am, first.clamp, first.coding, first.synchronized)
        for d in drivers:
            if type(d) is not cls:
                raise NotImplementedError(f"a {type(d).__name__} cannot share lanes with a {cls.__name__}")
            if (d.win.base, d.win.am, d.clamp, d.coding, d.synchronized) != key:
                raise NotImplementedError("the lanes' VMIVME-4116 drivers differ in board address, clamp, coding "
                                          "or update jumper")
        obj = cls.__new__(cls)
        obj.bus = bus
        obj.coding = first.coding
        obj.synchronized = first.synchronized
        obj.calibration = first.calibration  # lane 0's; each lane's own in _cal_offset_v/_cal_gain
        obj.clamp = first.clamp
        obj.clamp_events = stack([d.clamp_events for d in drivers])
        obj.win = BoardWindow(bus, first.win.base, VMI4116_REGMAP, first.win.am)
        obj.zero_code = first.zero_code
        obj._holding = [stack([d._holding[ch] for d in drivers]) for ch in range(VMI4116_CHANNELS)]
        obj._output = [stack([d._output[ch] for d in drivers]) for ch in range(VMI4116_CHANNELS)]
        obj._lanes = bus.lanes
        obj._cal_offset_v = tuple(stack([d.calibration.offset_v[ch] for d in drivers])
                                  for ch in range(VMI4116_CHANNELS))
        obj._cal_gain = tuple(stack([d.calibration.gain[ch] for d in drivers]) for ch in range(VMI4116_CHANNELS))
        # update, zero, _load and read_back_counts run as they are on lane codes
        for name in ("code_for", "write_many", "write_counts"):
            setattr(obj, name, getattr(obj, "_lane_" + name))
        return obj

    def _lane_code_for(self, channel: int, volts: LaneValue) -> tuple[LaneValue, LaneValue]:
        self._check_channel(channel)
        # Calibration.correct, per lane: the same two operations
        command = (volts - self._cal_offset_v[channel]) / self._cal_gain[channel]
        if not isinstance(command, np.ndarray):
            code, clipped = vmi4116_volts_to_code(command, self.coding)
            if clipped and not self.clamp:
                raise Vmi4116RangeError(channel, float(volts), command)
            return code, clipped
        codes, outside, invalid = vmi4116_volts_to_codes(command, self.coding)
        self._lanes.eject(invalid, f"VMIVME-4116 channel {channel}: the command is not a number (the driver raises)")
        if not self.clamp:
            self._lanes.eject(outside, f"VMIVME-4116 channel {channel}: a command outside the output range "
                                       "(Vmi4116RangeError)")
        return codes, outside

    def _lane_write_many(self, commands: Mapping[int, LaneValue], update: bool = True) -> DacWriteResult:
        # write_many in lanes: codes per lane (a lane a scalar driver would refuse is ejected, the
        # others written); ``clamped`` lists the channels clamped in some live lane, and
        # clamp_events counts per lane
        codes, clamped, events = lane_codes(self.code_for, commands, self._lanes)
        for ch, code in codes.items():
            self._load(ch, code)
        if update and codes:
            self.update()
        self.clamp_events = self.clamp_events + events
        return DacWriteResult(codes, clamped, update and bool(codes))

    def _lane_write_counts(self, channel: int, code: LaneValue, update: bool = True) -> None:
        self._check_channel(channel)
        bad = (code < 0) | (code > _CODE_MAX)
        if isinstance(bad, np.ndarray):
            self._lanes.eject(bad, f"VMIVME-4116 channel {channel}: a code outside 0..0xFFFF (the driver raises)")
        elif bad:
            raise ValueError(f"DAC code {code} is outside 0..0xFFFF")
        self._load(channel, code)
        if update:
            self.update()
