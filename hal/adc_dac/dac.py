"""Driver of the 8-channel 12-bit double-buffered DAC board (register map :mod:`hal.adc_dac.dac_regs`).

Volts at the API (±10 V, calibration applied). Writes go to the holding registers; an update
strobe moves them to the outputs — one strobe for all channels written by
:meth:`DacDriver.write_many`, so several joints' commands change in the same instant.

Out-of-range commands raise :class:`DacRangeError` by default. With ``clamp=True`` the command
is clamped to the nearest end code instead, and that is reported: the returned
:class:`DacWriteResult` lists the clamped channels and :attr:`DacDriver.clamp_events` counts them.

Example::

    dac = DacDriver(crate, 0x7000)
    dac.write_volts(0, 2.5)                          # load and update channel 0
    dac.write_many({0: 1.0, 1: -1.0, 2: 0.25})       # one simultaneous strobe
    dac.write_volts(3, 4.0, update=False); dac.update([3])

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`DacDriver.from_lanes` stacks B drivers (one
per instance) into one on a bus of lanes. Its :meth:`~DacDriver.write_many` takes volts per lane
(a float, or a ``(B,)`` array) and loads codes per lane, converted with the same float math as
one driver's (:func:`~hal.adc_dac.conversions.dac_volts_to_codes`) and each lane's calibration;
a command one instance's driver would refuse (NaN, or out of range without ``clamp``) ejects
that lane instead of raising.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import (
    DAC_V_MAX,
    DAC_V_MIN,
    AdcDacError,
    BoardIdError,
    dac_volts_to_code,
    dac_volts_to_codes,
)
from hal.adc_dac.dac_regs import DAC_BOARD_ID, DAC_CHANNELS, DAC_REGMAP
from hal.lanes import LaneSet, LaneValue, stack
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.window import BoardWindow

_CSR = DAC_REGMAP["CSR"]
#: DATAn by channel, by name (BoardWindow keeps the resolved cycle per register name)
_DATA_REGS = tuple(DAC_REGMAP[f"DATA{i}"].name for i in range(DAC_CHANNELS))


class DacRangeError(AdcDacError, ValueError):
    """A DAC command is outside what the converter can output."""

    def __init__(self, channel: int, volts: float, command_v: float) -> None:
        self.channel = channel
        self.volts = volts
        self.command_v = command_v
        cal = "" if command_v == volts else f" (calibrated command {command_v:+.4f} V)"
        super().__init__(
            f"DAC channel {channel}: {volts:+.4f} V{cal} is outside the output range "
            f"{DAC_V_MIN:+.4f}..{DAC_V_MAX:+.4f} V; limit the command upstream or open the driver with clamp=True"
        )


@dataclass(frozen=True)
class DacWriteResult:
    """What a write did: the code loaded per channel, and which channels were clamped."""

    codes: dict[int, int]
    clamped: tuple[int, ...] = ()
    updated: bool = True


class DacDriver:
    """Driver of one DAC board.

    Args:
        bus: the VME bus.
        base: board base address.
        space: address space or AM of the board window.
        calibration: per-channel offset/gain (8 channels) of the outputs; identity if None.
        clamp: clamp out-of-range commands (and report them) instead of raising.

    Raises:
        BoardIdError: the ID register does not read 0xDA08.
    """

    CHANNELS = DAC_CHANNELS
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
    ) -> None:
        self.bus = bus
        self.win = BoardWindow(bus, base, DAC_REGMAP, space)
        self.win.check_id(DAC_BOARD_ID, "DAC", error=BoardIdError)
        self.calibration = calibration or Calibration.identity(DAC_CHANNELS)
        if self.calibration.channels != DAC_CHANNELS:
            raise ValueError(f"DAC calibration has {self.calibration.channels} channels, the board has 8")
        self.clamp = clamp
        self.clamp_events = 0  #: number of channel writes that were clamped (clamp=True)

    # --- conversion -----------------------------------------------------------------------
    def code_for(self, channel: int, volts: float) -> tuple[int, bool]:
        """The code that makes output ``channel`` produce ``volts`` (calibration applied) and
        whether it had to be clamped. Raises :class:`DacRangeError` unless ``clamp``."""
        self._check_channel(channel)
        command = self.calibration.correct(channel, float(volts))
        code, clipped = dac_volts_to_code(command)
        if clipped and not self.clamp:
            raise DacRangeError(channel, float(volts), command)
        return code, clipped

    # --- writes -----------------------------------------------------------------------------
    def write_volts(self, channel: int, volts: float, update: bool = True) -> DacWriteResult:
        """Load ``volts`` into ``channel``'s holding register; strobe it to the output if ``update``."""
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
        data = _DATA_REGS
        for ch, code in codes.items():
            self.win.write(data[ch], code)
        if update and codes:
            self.update(codes)
        self.clamp_events += len(clamped)
        return DacWriteResult(codes, tuple(clamped), update and bool(codes))

    def write_counts(self, channel: int, code: int, update: bool = True) -> None:
        """Load a raw offset-binary code (no calibration, no range check beyond 12 bits)."""
        self._check_channel(channel)
        if not 0 <= code <= 0xFFF:
            raise ValueError(f"DAC code {code} is outside 0..0xFFF")
        self.win.write(f"DATA{channel}", code)
        if update:
            self.update([channel])

    def update(self, channels: Iterable[int] | None = None) -> None:
        """Strobe holding → output: all channels (``None``) or the given ones, simultaneously."""
        if channels is None:
            self.win.write("CSR", _CSR.pack(UPDATE_ALL=1))
            return
        mask = 0
        for ch in channels:
            self._check_channel(ch)
            mask |= 1 << ch
        if mask:
            self.win.write("UPDATE", mask)

    def reset(self) -> None:
        """Board reset: all holding registers and outputs to 0 V (0x800)."""
        self.win.write("CSR", _CSR.pack(RESET=1))

    # --- readback ---------------------------------------------------------------------------
    def read_back_counts(self, channel: int) -> int:
        """The code driving output ``channel`` now (OUTn readback)."""
        self._check_channel(channel)
        return self.win.read(f"OUT{channel}") & 0xFFF

    def read_holding_counts(self, channel: int) -> int:
        """The code waiting in ``channel``'s holding register (DATAn)."""
        self._check_channel(channel)
        return self.win.read(f"DATA{channel}") & 0xFFF

    @property
    def settling(self) -> bool:
        """``True`` while an output is still settling after an update (in lanes: per lane)."""
        return self._read_settling()

    def _read_settling(self) -> bool:
        return bool(self.win.read_field("CSR", "SETTLING"))

    @staticmethod
    def _check_channel(channel: int) -> None:
        if not 0 <= channel < DAC_CHANNELS:
            raise ValueError(f"DAC channel {channel} is not 0..{DAC_CHANNELS - 1}")

    # --- lanes (batched lockstep, hal.lanes) -------------------------------------------------
    @classmethod
    def from_lanes(cls, drivers: Sequence[DacDriver], bus: VmeBus) -> DacDriver:
        """One driver in lane mode for the B scalar ``drivers`` (lane order, each opened on its
        instance's crate) on ``bus``, the crate of their lanes: the same board (base, space) and
        ``clamp`` in every lane; each lane keeps its calibration and its clamp count. No bus cycle
        (the drivers' set-up was made by each scalar driver)."""
        first = drivers[0]
        if not isinstance(bus.lanes, LaneSet):
            raise ValueError("a DAC driver in lanes needs a bus of lanes (bus.lanes)")
        for d in drivers:
            if type(d) is not cls:
                raise NotImplementedError(f"a {type(d).__name__} cannot share lanes with a {cls.__name__}")
            if (d.win.base, d.win.am, d.clamp) != (first.win.base, first.win.am, first.clamp):
                raise NotImplementedError("the lanes' DAC drivers differ in board address or clamp")
        obj = cls.__new__(cls)
        obj.bus = bus
        obj.win = BoardWindow(bus, first.win.base, DAC_REGMAP, first.win.am)
        obj.calibration = first.calibration  # lane 0's; each lane's own in _cal_offset_v/_cal_gain
        obj.clamp = first.clamp
        obj.clamp_events = stack([d.clamp_events for d in drivers])
        obj._lanes = bus.lanes
        obj._cal_offset_v = tuple(stack([d.calibration.offset_v[ch] for d in drivers]) for ch in range(DAC_CHANNELS))
        obj._cal_gain = tuple(stack([d.calibration.gain[ch] for d in drivers]) for ch in range(DAC_CHANNELS))
        for name in ("code_for", "write_many", "write_counts", "_read_settling"):
            setattr(obj, name, getattr(obj, "_lane_" + name.lstrip("_")))
        return obj

    def _lane_code_for(self, channel: int, volts: LaneValue) -> tuple[LaneValue, LaneValue]:
        self._check_channel(channel)
        # Calibration.correct, per lane: the same two operations
        command = (volts - self._cal_offset_v[channel]) / self._cal_gain[channel]
        if not isinstance(command, np.ndarray):
            code, clipped = dac_volts_to_code(command)
            if clipped and not self.clamp:
                raise DacRangeError(channel, float(volts), command)
            return code, clipped
        codes, outside, invalid = dac_volts_to_codes(command)
        self._lanes.eject(invalid, f"DAC channel {channel}: the command is not a number (the driver raises)")
        if not self.clamp:
            self._lanes.eject(outside, f"DAC channel {channel}: a command outside the output range (DacRangeError)")
        return codes, outside

    def _lane_write_many(self, commands: Mapping[int, LaneValue], update: bool = True) -> DacWriteResult:
        # write_many in lanes: codes per lane (a lane a scalar driver would refuse is ejected,
        # the others written); ``clamped`` lists the channels clamped in some live lane, and
        # clamp_events counts per lane
        codes, clamped, events = lane_codes(self.code_for, commands, self._lanes)
        data = _DATA_REGS
        for ch, code in codes.items():
            self.win.write(data[ch], code)
        if update and codes:
            self.update(codes)
        self.clamp_events = self.clamp_events + events
        return DacWriteResult(codes, clamped, update and bool(codes))

    def _lane_write_counts(self, channel: int, code: LaneValue, update: bool = True) -> None:
        self._check_channel(channel)
        bad = (code < 0) | (code > 0xFFF)
        if isinstance(bad, np.ndarray):
            self._lanes.eject(bad, f"DAC channel {channel}: a code outside 0..0xFFF (the driver raises)")
        elif bad:
            raise ValueError(f"DAC code {code} is outside 0..0xFFF")
        self.win.write(f"DATA{channel}", code)
        if update:
            self.update([channel])

    def _lane_read_settling(self) -> LaneValue:
        return self.win.read_field("CSR", "SETTLING") != 0


def lane_codes(code_for: Any, commands: Mapping[int, LaneValue],
               lanes: LaneSet) -> tuple[dict[int, Any], tuple[int, ...], Any]:
    """A DAC driver's ``write_many`` conversions in lanes: per channel the codes of
    ``code_for(channel, volts)`` (which ejects the lanes a scalar driver would refuse), the channels
    clamped in some live lane, and the clamps per lane (every DAC driver of lanes uses it)."""
    codes: dict[int, Any] = {}
    clamped: list[int] = []
    events: Any = 0
    for ch, v in commands.items():
        codes[ch], c = code_for(ch, v)
        events = events + c
        if lanes.any(c):
            clamped.append(ch)
    return codes, tuple(clamped), events
