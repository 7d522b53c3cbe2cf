"""Driver of the VMIC VMIVME-3113A scanning 12-bit ADC, 64 channels (``docs/boards/vmivme-3113a.md``;
register map :mod:`hal.adc_dac.vmivme3113a_regs`, conversions :mod:`hal.adc_dac.vmivme3113a_format`).

The board runs in its autoscanning mode, as the EPICS support it is documented from does: the
sequencer converts the 64 channels round and round, and a read of CHk returns channel k's latest
code (at most one scan, 640 µs, old). So a per-tick :meth:`Vmivme3113aDriver.scan` is a block of
D16 reads with no start and no wait. The role's interface is the reference ADC driver's
(:class:`hal.adc_dac.AdcDriver`) as the servo uses it: ``scan(last)`` → calibrated volts, a
``calibration`` attribute, and ``lsb_v`` for the volts of one code.

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`Vmivme3113aDriver.from_lanes` makes one driver
of the B boards of a bus of lanes; its scans return arrays of shape (k, B) (the section "lanes" at
the end of this module).

Example::

    adc = Vmivme3113aDriver(crate, 0x8500)          # ±10 V jumpers, offset binary
    pots = adc.scan(6)                               # channels 0..6, numpy array of volts
    code = adc.read_counts(16)                       # one channel's offset-binary code
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hal.adc_dac.adc import AdcTimeoutError
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import BoardIdError
from hal.adc_dac.vmivme3113a_format import (
    Vmi3113aFormat,
    Vmi3113aRange,
    code_from_word,
    codes_from_words,
    lsb_v,
    volts_from_code,
)
from hal.adc_dac.vmivme3113a_regs import (
    MODE_AUTOSCANNING,
    VMI3113A_BOARD_ID,
    VMI3113A_CHANNELS,
    VMI3113A_DATA_OFFSET,
    VMI3113A_REGMAP,
)
from hal.lanes import LaneSet, stack
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.types import Width
from hal.vme.window import BoardWindow

_CSR = VMI3113A_REGMAP["CSR"]
_B = {f.name: f.mask for f in _CSR.fields}
_MODE = _CSR.field("MODE")


@dataclass(frozen=True)
class Vmi3113aStatus:
    """A decoded CSR read (the read clears the two status bits on the board)."""

    new_data_ready: bool
    end_of_scan: bool
    fail_led_off: bool
    twos_complement: bool
    mode: int

    @classmethod
    def decode(cls, csr: int) -> Vmi3113aStatus:
        return cls(
            new_data_ready=bool(csr & _B["NEW_DATA_READY"]),
            end_of_scan=bool(csr & _B["END_OF_SCAN"]),
            fail_led_off=bool(csr & _B["FAIL_LED_OFF"]),
            twos_complement=bool(csr & _B["TWOS_COMPLEMENT"]),
            mode=_MODE.get(csr),
        )


class Vmivme3113aDriver:
    """Driver of one VMIVME-3113A in autoscanning mode.

    Args:
        bus: the VME bus.
        base: board base address (A16 short I/O; the board's jumpers J9 A08–A15).
        space: address space or AM (the board answers supervisory short I/O, AM 0x2D).
        calibration: per-channel offset/gain (64 channels), applied to volts; identity if None.
        input_range: the range the board's jumpers select (``"bipolar_10v"``, ``"bipolar_5v"``,
            ``"unipolar_10v"``): the board cannot report it, so the driver is told.
        data_format: ``"offset_binary"`` or ``"twos_complement"`` (CSR.TWOS_COMPLEMENT);
            two's complement is refused on the unipolar range, where it means nothing.
        conversion_time_s: the board's time per channel; the driver waits one 64-channel scan
            after the reset before its first END_OF_SCAN poll.
        poll_interval_s, timeout_s: END_OF_SCAN polling after that, and how long beyond the
            first scan it may take before :class:`AdcTimeoutError`.

    Raises:
        BoardIdError: ID does not read 0x1100 (wrong base address or board).
    """

    CHANNELS = VMI3113A_CHANNELS
    #: the per-lane part of a driver of lanes (:meth:`from_lanes`); None: one board
    _lanes: _Vmi3113aDriverLanes | None = None

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        calibration: Calibration | None = None,
        input_range: Vmi3113aRange | str = Vmi3113aRange.BIPOLAR_10V,
        data_format: Vmi3113aFormat | str = Vmi3113aFormat.OFFSET_BINARY,
        conversion_time_s: float = 10e-6,
        poll_interval_s: float = 20e-6,
        timeout_s: float = 5e-3,
    ) -> None:
        self.input_range = Vmi3113aRange.parse(input_range)
        self.data_format = Vmi3113aFormat.parse(data_format)
        if self.data_format is Vmi3113aFormat.TWOS_COMPLEMENT and not self.input_range.bipolar:
            raise ValueError("VMIVME-3113A: two's complement data on the unipolar 0..10 V range means nothing; "
                             "use offset_binary")
        self.bus = bus
        self.win = BoardWindow(bus, base, VMI3113A_REGMAP, space)
        self.win.check_id(VMI3113A_BOARD_ID, "VMIVME-3113A", error=BoardIdError)
        self.calibration = calibration or Calibration.identity(VMI3113A_CHANNELS)
        if self.calibration.channels != VMI3113A_CHANNELS:
            raise ValueError(f"VMIVME-3113A calibration has {self.calibration.channels} channels, "
                             f"the board has {VMI3113A_CHANNELS}")
        self.conversion_time_s = float(conversion_time_s)
        self.poll_interval_s = float(poll_interval_s)
        self.timeout_s = float(timeout_s)
        self._lsb_v = lsb_v(self.input_range)
        self._v0 = self.input_range.v0
        self._data_address = self.win.base + VMI3113A_DATA_OFFSET
        self._plans: dict[int, tuple[np.ndarray, int]] = {}
        # As the EPICS support does (drvVmi3113A.c:103-104): reset, then autoscanning with the
        # FAIL LED off; plus the data format.
        self.win.write("CSR", _B["SOFTWARE_RESET"])
        twos = _B["TWOS_COMPLEMENT"] if self.data_format is Vmi3113aFormat.TWOS_COMPLEMENT else 0
        self.win.write("CSR", _B["FAIL_LED_OFF"] | _MODE.put(0, MODE_AUTOSCANNING) | twos)
        self._wait_first_scan()

    @classmethod
    def from_lanes(cls, drivers: Sequence[Vmivme3113aDriver], bus: VmeBus) -> Vmivme3113aDriver:
        """One driver of lanes for ``drivers`` (one per lane of ``bus``, in lane order; opened as
        scalar runs open them) on ``bus``, a bus of lanes: :meth:`scan` and :meth:`scan_counts`
        then return arrays of shape (k, B) (the section "lanes" at the end of this module). No bus cycle."""
        return _stack_3113a_drivers(cls, drivers, bus)

    # --- conversions (named: the servo asks the driver, never the reference ADC's formulas) -----
    @property
    def lsb_v(self) -> float:
        """Volts of one code in the jumpered range."""
        return self._lsb_v

    # --- status ---------------------------------------------------------------------------
    def status(self) -> Vmi3113aStatus:
        """Read the CSR (the read clears NEW_DATA_READY and END_OF_SCAN on the board)."""
        return Vmi3113aStatus.decode(self.win.read("CSR"))

    def _wait_first_scan(self) -> None:
        """After the reset the data words hold 0 until the sequencer has been round once."""
        scan_s = VMI3113A_CHANNELS * self.conversion_time_s
        deadline = self.bus.now() + scan_s + self.timeout_s
        self.bus.delay(scan_s)
        while True:
            csr = self.win.read("CSR")
            if csr & _B["END_OF_SCAN"]:
                return
            if self.bus.now() >= deadline:
                raise AdcTimeoutError("VMIVME-3113A first autoscan", scan_s + self.timeout_s, csr)
            self.bus.delay(self.poll_interval_s)

    # --- reads ------------------------------------------------------------------------------
    @property
    def fresh_after_s(self) -> float:
        """How long after a change at an input a read is sure to show it: the sequencer's phase
        is unknown, so one scan and one conversion (65 conversion times, 650 µs). A procedure
        that sets a level and reads it back (a reference, a DAC loopback), or averages
        independent conversions, waits this long first; the servo's tick takes the latest codes
        (the reference ADC converts after each call: 0 there)."""
        return (VMI3113A_CHANNELS + 1) * self.conversion_time_s

    def read_counts(self, channel: int, gain: int = 1) -> int:
        """Channel ``channel``'s latest code (offset binary 0..0xFFF, whatever the data format):
        one read, up to one scan old (see :attr:`fresh_after_s`)."""
        self._check(channel, gain)
        word = self.win.read_offset(VMI3113A_DATA_OFFSET + 2 * channel, Width.D16)
        return code_from_word(word, self.data_format)

    def read_volts(self, channel: int, gain: int = 1) -> float:
        """Channel ``channel``'s latest reading (see :meth:`read_counts`), calibrated input volts."""
        code = self.read_counts(channel, gain)
        return self.calibration.correct(channel, volts_from_code(code, self.input_range))

    def scan_counts(self, channels: int | Sequence[int], gain: int = 1) -> np.ndarray:
        """Codes of CH0..CHmax in one block read, in the order of ``channels`` (see :meth:`scan`)."""
        chans, last = self._plan(channels, gain)
        words = self.bus.read_block(self._data_address, last + 1, space=self.win.am, width=Width.D16)
        return codes_from_words(np.asarray(words, dtype=np.int64), self.data_format)[chans]

    def scan(self, channels: int | Sequence[int], gain: int = 1) -> np.ndarray:
        """Calibrated volts of the latest autoscan: ``channels`` is the last channel (0..last,
        index = channel) or a list (the board's words 0..max are read, the result follows the
        list). ``gain`` must be 1: the board has no programmable gain that the sources name."""
        chans, _ = self._plan(channels, gain)
        volts = self._v0 + self.scan_counts(channels, gain) * self._lsb_v
        cal = self.calibration
        return (volts - np.asarray(cal.offset_v)[chans]) / np.asarray(cal.gain)[chans]

    def _plan(self, channels: int | Sequence[int], gain: int) -> tuple[np.ndarray, int]:
        if isinstance(channels, int | np.integer):
            key = int(channels)
            plan = self._plans.get(key)
            if plan is None:
                self._check(key, gain)
                plan = self._plans[key] = (np.arange(key + 1, dtype=np.intp), key)
            elif gain != 1:
                self._check(key, gain)
            return plan
        chans = [int(c) for c in channels]
        if not chans:
            raise ValueError("scan needs at least one channel")
        for c in chans:
            self._check(c, gain)
        return np.asarray(chans, dtype=np.intp), max(chans)

    @staticmethod
    def _check(channel: int, gain: int) -> None:
        if not 0 <= channel < VMI3113A_CHANNELS:
            raise ValueError(f"VMIVME-3113A channel {channel} is not 0..{VMI3113A_CHANNELS - 1}")
        if gain != 1:
            raise ValueError(f"VMIVME-3113A gain {gain!r}: the board has gain 1 only (its range is set by jumpers)")


# --- lanes: one driver for the B boards of a bus of lanes (batched lockstep, issue #34) -----------
# A driver of lanes makes its scalar drivers' bus cycles once for every lane: the words it reads
# hold a value per lane (hal.lanes). Vmivme3113aDriver.from_lanes selects, once, the steps that
# differ from the scalar code above (which runs unchanged on a scalar driver):
# * the block read of CH0..CHmax gives a word per channel and lane: scan_counts returns codes of
#   shape (k, B), scan calibrated volts of shape (k, B) (each lane's column: the scalar driver's
#   (k,) operations, element by element, so the same bits); read_volts a lane value;
# * each lane keeps its scalar driver's calibration ((k, B) where the lanes' calibrations differ,
#   (k, 1) where they are alike); a calibration assigned to the driver of lanes is every lane's;
# * nothing in a tick branches on a lane's value (autoscanning: no start, no wait); status() decodes
#   a CSR into one record's bools, which lanes have no form of: NotImplementedError.
# Out of scope (NotImplementedError): drivers differing in address, range, format or timing.

def _stack_3113a_drivers(cls: type[Vmivme3113aDriver], drivers: Sequence[Vmivme3113aDriver],
                         bus: VmeBus) -> Vmivme3113aDriver:
    """:meth:`Vmivme3113aDriver.from_lanes`: one driver for ``drivers`` (one per lane, in lane order)."""
    lanes = bus.lanes
    if lanes is None:
        raise ValueError("Vmivme3113aDriver.from_lanes needs a bus of lanes (its .lanes is a hal.lanes.LaneSet)")
    if len(drivers) != lanes.size:
        raise ValueError(f"{len(drivers)} VMIVME-3113A drivers for a bus of {lanes.size} lanes")
    first = drivers[0]

    def same(d: Vmivme3113aDriver) -> tuple[object, ...]:
        return (d.win.base, d.win.am, d.input_range, d.data_format, d.conversion_time_s, d.poll_interval_s,
                d.timeout_s)

    for d in drivers:
        if type(d) is not cls:
            raise NotImplementedError(f"a {type(d).__name__} is not a {cls.__name__}; it cannot stack with one")
        if same(d) != same(first):
            raise NotImplementedError(f"VMIVME-3113A at 0x{d.win.base:X}: drivers that differ in address, range, "
                                      "data format or timing cannot run in lanes")
    drv = cls.__new__(cls)
    drv.bus = bus
    drv.win = BoardWindow(bus, first.win.base, VMI3113A_REGMAP, first.win.am)
    drv.input_range, drv.data_format = first.input_range, first.data_format
    drv.calibration = first.calibration
    drv.conversion_time_s, drv.poll_interval_s, drv.timeout_s = (first.conversion_time_s, first.poll_interval_s,
                                                                 first.timeout_s)
    drv._lsb_v, drv._v0, drv._data_address = first._lsb_v, first._v0, first._data_address
    drv._plans = dict(first._plans)
    ls = _Vmi3113aDriverLanes(drv, [d.calibration for d in drivers], lanes)
    drv._lanes = ls
    # the lane-mode steps, selected once (the scalar methods run unchanged on a scalar driver)
    drv.scan = ls.scan  # type: ignore[method-assign]
    drv.scan_counts = ls.scan_counts  # type: ignore[method-assign]
    drv.read_volts = ls.read_volts  # type: ignore[method-assign]
    drv.status = ls.status  # type: ignore[method-assign]
    return drv


class _Vmi3113aDriverLanes:
    """The per-lane part of a driver of lanes, and its lane-mode steps."""

    def __init__(self, driver: Vmivme3113aDriver, calibrations: Sequence[Calibration], lanes: LaneSet) -> None:
        self.driver, self.lanes, self.n = driver, lanes, lanes.size
        #: each lane's calibration (lane order), and the driver's when they were taken
        self.calibrations = tuple(calibrations)
        self._bound = driver.calibration
        #: per channel list: the calibration's offsets and gains over the lanes, (k, B) or (k, 1)
        self._cal: dict[Any, tuple[np.ndarray, np.ndarray]] = {}

    def _calibrations(self) -> tuple[Calibration, ...]:
        d = self.driver
        if d.calibration is not self._bound:  # assigned to the driver of lanes: every lane's from now on
            self._bound = d.calibration
            self.calibrations = (d.calibration,) * self.n
            self._cal.clear()
        return self.calibrations

    def scan_counts(self, channels: int | Sequence[int], gain: int = 1) -> np.ndarray:
        """:meth:`Vmivme3113aDriver.scan_counts` of every lane: codes, shape (k, B)."""
        d = self.driver
        chans, last = d._plan(channels, gain)
        words = d.bus.read_block(d._data_address, last + 1, space=d.win.am, width=Width.D16)
        w = np.empty((last + 1, self.n), dtype=np.int64)
        for k, word in enumerate(words):  # a word every lane holds alike is one int
            w[k] = word
        return codes_from_words(w, d.data_format)[chans]

    def scan(self, channels: int | Sequence[int], gain: int = 1) -> np.ndarray:
        """:meth:`Vmivme3113aDriver.scan` of every lane: calibrated volts, shape (k, B)."""
        d = self.driver
        chans, _ = d._plan(channels, gain)
        volts = d._v0 + self.scan_counts(channels, gain) * d._lsb_v
        cals = self._calibrations()
        key = channels if isinstance(channels, int) else tuple(chans.tolist())
        arrays = self._cal.get(key)
        if arrays is None:
            offset, cal_gain = (stack([np.asarray(getattr(c, name))[chans] for c in cals])
                                for name in ("offset_v", "gain"))
            arrays = self._cal[key] = (offset if offset.ndim == 2 else offset[:, None],
                                       cal_gain if cal_gain.ndim == 2 else cal_gain[:, None])
        # the scalar scan's operations, element by element (each lane's arrays broadcast on its column)
        return (volts - arrays[0]) / arrays[1]  # type: ignore[no-any-return]

    def read_volts(self, channel: int, gain: int = 1) -> Any:
        """:meth:`Vmivme3113aDriver.read_volts` of every lane: a lane value (volts_from_code's and
        Calibration.correct's operations, lane by lane)."""
        d = self.driver
        code = d.read_counts(channel, gain)
        volts = d.input_range.v0 + code * lsb_v(d.input_range)
        cals = self._calibrations()
        offset = stack([c.offset_v[channel] for c in cals])
        cal_gain = stack([c.gain[channel] for c in cals])
        return (volts - offset) / cal_gain

    def status(self) -> Vmi3113aStatus:
        raise NotImplementedError("VMIVME-3113A status() decodes one board's CSR: no lane form (read CSR instead)")
