"""Driver of the 16-channel 12-bit ADC board (register map :mod:`hal.adc_dac.adc_regs`).

Talks only to a :class:`hal.vme.VmeBus`. Volts at the API (calibration applied), raw 12-bit
codes on request. Single conversions are polled by default; after :meth:`AdcDriver.enable_interrupts`
they wait for the end-of-conversion interrupt instead. :meth:`AdcDriver.scan` uses the board's
sequencer and reads the result buffer with one block transfer — the fast path for the servo
loop (one start, one wait, one block read per tick).

Lanes (batched lockstep, :mod:`hal.lanes`): :meth:`AdcDriver.from_lanes` makes one driver of the
B boards of a bus of lanes; its scans return arrays of shape (k, B) (the section "lanes" at the
end of this module).

Example::

    adc = AdcDriver(crate, 0x6000)
    v = adc.read_volts(3)                  # ±10 V range, gain 1, calibrated volts
    pots = adc.scan(5)                     # channels 0..5, numpy array of volts
    code = adc.read_counts(3, gain=4)      # raw 12-bit code
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from hal.adc_dac.adc_regs import (
    ADC_BOARD_ID,
    ADC_BUFFER_OFFSET,
    ADC_CHANNELS,
    ADC_REGMAP,
    CSR_CONFIG_MASK,
)
from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import (
    ADC_FULL_SCALE_V,
    N_CODES,
    AdcDacError,
    AdcRange,
    BoardIdError,
    adc_code_to_volts,
    adc_lsb,
    check_gain,
    gain_code,
)
from hal.lanes import LaneSet, lane, stack
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.types import Width
from hal.vme.window import BoardWindow

_CSR = ADC_REGMAP["CSR"]
_B = {f.name: f.mask for f in _CSR.fields}
_LEVEL = _CSR.field("IRQ_LEVEL")
_CSR_LOW = ADC_REGMAP["CSR"].offset + 1  # D8 address of the action/status byte


class AdcError(AdcDacError):
    """Base class of ADC driver errors."""


class AdcTimeoutError(AdcError):
    """The board never reported the end of a conversion/scan within the timeout."""

    def __init__(self, what: str, timeout_s: float, csr: int) -> None:
        self.timeout_s = timeout_s
        self.csr = csr
        super().__init__(
            f"ADC {what} did not finish within {timeout_s * 1e6:.0f} µs (CSR=0x{csr:04X}); "
            "check the board's clock/conversion time, the IRQ level and vector, or raise timeout_s"
        )


@dataclass(frozen=True)
class AdcStatus:
    """Decoded CSR."""

    busy: bool
    done: bool
    early_read: bool
    overrun: bool
    irq_pending: bool
    irq_enabled: bool
    irq_level: int
    range: AdcRange

    @classmethod
    def decode(cls, csr: int) -> AdcStatus:
        return cls(
            busy=bool(csr & _B["BUSY"]),
            done=bool(csr & _B["DONE"]),
            early_read=bool(csr & _B["EARLY"]),
            overrun=bool(csr & _B["OVERRUN"]),
            irq_pending=bool(csr & _B["IRQ_PEND"]),
            irq_enabled=bool(csr & _B["IRQ_EN"]),
            irq_level=_LEVEL.get(csr),
            range=AdcRange.UNIPOLAR_10V if csr & _B["RANGE"] else AdcRange.BIPOLAR_10V,
        )


class _ScanPlan:
    """What one form of :meth:`AdcDriver.scan` needs each time: channels, gains, and the code →
    volts → calibrated volts arrays (bound to a calibration and range, rebound when they change)."""

    def __init__(self, chans: list[int], last: int, gains: list[int]) -> None:
        self.chans = np.asarray(chans, dtype=np.intp)
        self.last = last
        self.gains = gains
        self.what = f"scan of channels 0..{last}"
        self.cal: Calibration | None = None
        self.range: AdcRange | None = None
        self.bipolar = True
        self.v0 = self.lsb = self.offset_v = self.cal_gain = np.zeros(0)

    def bind(self, cal: Calibration, rng: AdcRange) -> None:
        g = np.asarray([self.gains[c] for c in self.chans], dtype=float)
        self.bipolar = rng is AdcRange.BIPOLAR_10V
        if self.bipolar:
            self.lsb = 2 * ADC_FULL_SCALE_V / g / N_CODES
            self.v0 = -ADC_FULL_SCALE_V / g
        else:
            self.lsb = ADC_FULL_SCALE_V / g / N_CODES
            self.v0 = np.zeros_like(g)
        self.offset_v = np.asarray(cal.offset_v, dtype=float)[self.chans]
        self.cal_gain = np.asarray(cal.gain, dtype=float)[self.chans]
        self.cal, self.range = cal, rng


class AdcDriver:
    """Driver of one ADC board.

    Args:
        bus: the VME bus.
        base: board base address (A16 by default).
        space: address space or AM of the board window.
        calibration: per-channel offset/gain (16 channels), applied to volts; identity if None.
        range: input range programmed at start-up (±10 V or 0..10 V).
        conversion_time_s: nominal time per channel; the driver waits this long before its
            first status poll (a hint for efficiency, not a correctness requirement).
        poll_interval_s: time between status polls after that.
        timeout_s: extra time allowed beyond the nominal conversion time before
            :class:`AdcTimeoutError`.

    Raises:
        BoardIdError: the ID register does not read 0xAD16 (wrong base address or board).
    """

    CHANNELS = ADC_CHANNELS
    #: the per-lane part of a driver of lanes (:meth:`from_lanes`); None: one board
    _lanes: _AdcDriverLanes | None = None
    #: how long after a change at an input a read is sure to show it (every read converts after
    #: its call here; an autoscanning board's driver names its scan time)
    fresh_after_s = 0.0

    def __init__(
        self,
        bus: VmeBus,
        base: int,
        *,
        space: SpaceLike = "A16",
        calibration: Calibration | None = None,
        range: AdcRange | str = AdcRange.BIPOLAR_10V,
        conversion_time_s: float = 15e-6,
        poll_interval_s: float = 2e-6,
        timeout_s: float = 1e-3,
    ) -> None:
        self.bus = bus
        self.win = BoardWindow(bus, base, ADC_REGMAP, space)
        self.win.check_id(ADC_BOARD_ID, "ADC", error=BoardIdError)
        self.calibration = calibration or Calibration.identity(ADC_CHANNELS)
        if self.calibration.channels != ADC_CHANNELS:
            raise ValueError(f"ADC calibration has {self.calibration.channels} channels, the board has 16")
        self.conversion_time_s = float(conversion_time_s)
        self.poll_interval_s = float(poll_interval_s)
        self.timeout_s = float(timeout_s)
        self._vector: int | None = None
        self._irq_count = 0
        self._scan_cfg: tuple[int, int, int] | None = None
        self._scan_plans: dict[tuple[int, int], _ScanPlan] = {}
        self.win.write("CSR", _B["RESET"])
        self.range = AdcRange.parse(range)
        self._config = _B["RANGE"] if self.range is AdcRange.UNIPOLAR_10V else 0
        self._write_config()

    @classmethod
    def from_lanes(cls, drivers: Sequence[AdcDriver], bus: VmeBus) -> AdcDriver:
        """One driver of lanes for ``drivers`` (one per lane of ``bus``, in lane order; set up as
        scalar runs set them up) on ``bus``, a bus of lanes: :meth:`scan` and :meth:`scan_counts`
        then return arrays of shape (k, B) (the section "lanes" at the end of this module). No bus cycle."""
        return _stack_adc_drivers(cls, drivers, bus)

    # --- configuration --------------------------------------------------------------------
    def _write_config(self) -> None:
        self.win.write("CSR", self._config & CSR_CONFIG_MASK)

    @property
    def lsb_v(self) -> float:
        """Volts of one code in the programmed range at gain 1 (what the servo's resolution
        figures use: every ADC driver of the role names it so)."""
        return adc_lsb(self.range)

    def set_range(self, rng: AdcRange | str) -> None:
        """Program the input range (affects the next conversion)."""
        self.range = AdcRange.parse(rng)
        self._config = (self._config & ~_B["RANGE"]) | (_B["RANGE"] if self.range is AdcRange.UNIPOLAR_10V else 0)
        self._write_config()

    def enable_interrupts(self, level: int, vector: int) -> None:
        """Interrupt-driven waits: program ``VECTOR``, ``IRQ_LEVEL`` and ``IRQ_EN``, and register
        the driver's handler for ``vector`` on the bus. The handler releases the board's RORA
        request by writing 1 to ``CSR.IRQ_PEND``."""
        if not 1 <= level <= 7:
            raise ValueError(f"IRQ level {level} is not 1..7")
        self.disable_interrupts()
        self.bus.register_irq_handler(vector, self._on_irq)
        self._vector = vector
        self.win.write("VECTOR", vector & 0xFF)
        self._config = _LEVEL.put(self._config, level) | _B["IRQ_EN"]
        self._write_config()

    def disable_interrupts(self) -> None:
        """Back to polled waits; unregisters the handler."""
        self._config &= ~(_B["IRQ_EN"] | _LEVEL.mask)
        self._write_config()
        if self._vector is not None:
            self.bus.unregister_irq_handler(self._vector)
            self._vector = None

    @property
    def interrupts_enabled(self) -> bool:
        return self._vector is not None

    @property
    def interrupts_taken(self) -> int:
        """Number of end-of-conversion interrupts the handler has serviced."""
        return self._irq_count

    def _on_irq(self, vector: int) -> None:
        self.win.read("CSR")  # the handler's first cycle (docs/boards/adc.md); the value is not kept
        self.win.write_offset(_CSR_LOW, _B["IRQ_PEND"], Width.D8)  # RORA release
        self._irq_count += 1

    # --- status -----------------------------------------------------------------------------
    def status(self) -> AdcStatus:
        return AdcStatus.decode(self.win.read("CSR"))

    def clear_flags(self) -> None:
        """Clear the sticky EARLY and OVERRUN flags."""
        self.win.write_offset(_CSR_LOW, _B["EARLY"] | _B["OVERRUN"], Width.D8)

    # --- single conversions -----------------------------------------------------------------
    def start_conversion(self, channel: int, gain: int = 1) -> None:
        """Select ``channel``/``gain`` and start one conversion; does not wait."""
        self._check_channel(channel)
        self.win.write("CHAN", (gain_code(gain) << 4) | channel)
        self.win.write_offset(_CSR_LOW, _B["START"], Width.D8)

    def read_data(self) -> tuple[int, int]:
        """Read DATA now: ``(channel, code)``. Before the conversion is done this is the stale
        word and the board sets its EARLY flag (see :meth:`status`)."""
        word = self.win.read("DATA")
        return word >> 12, word & 0xFFF

    def read_counts(self, channel: int, gain: int = 1) -> int:
        """Convert ``channel`` at ``gain`` and return the raw 12-bit code (no calibration)."""
        self.start_conversion(channel, gain)
        self._wait(1, f"conversion of channel {channel}")
        ch, code = self.read_data()
        if ch != channel:
            raise AdcError(f"ADC DATA holds channel {ch}, expected {channel}: another master started a conversion")
        return code

    def read_volts(self, channel: int, gain: int = 1) -> float:
        """Convert ``channel`` at ``gain``; calibrated input volts."""
        code = self.read_counts(channel, gain)
        return self.calibration.correct(channel, adc_code_to_volts(code, self.range, gain))

    # --- scans ------------------------------------------------------------------------------
    def scan_counts(self, channels: int | Sequence[int], gain: int | Mapping[int, int] = 1) -> np.ndarray:
        """Raw codes of a scan (see :meth:`scan`), in the order of ``channels``."""
        plan = self._scan_plan(channels, gain)
        return self._run_scan(plan)[plan.chans]

    def scan(self, channels: int | Sequence[int], gain: int | Mapping[int, int] = 1) -> np.ndarray:
        """Scan with the board's sequencer and return calibrated volts.

        ``channels`` is either the last channel (scan 0..last, result index = channel) or a
        list of channels (the board scans 0..max(list); the result follows the list order).
        ``gain`` is one gain for all channels or ``{channel: gain}`` (others at 1).

        The scan's plan (channel list, gain codes, conversion and calibration arrays) is kept
        per (channels, gain) when they are plain numbers, the servo loop's case: a tick then
        costs the bus cycles and a few array operations.
        """
        plan = self._scan_plan(channels, gain)
        codes = self._run_scan(plan)[plan.chans]
        cal = self.calibration
        if plan.cal is not cal or plan.range is not self.range:
            plan.bind(cal, self.range)
        # the same operations as adc_codes_to_volts and Calibration.correct_array
        volts = plan.v0 + codes * plan.lsb if plan.bipolar else codes * plan.lsb
        return (volts - plan.offset_v) / plan.cal_gain

    def _scan_plan(self, channels: int | Sequence[int], gain: int | Mapping[int, int]) -> _ScanPlan:
        key = (int(channels), int(gain)) if (isinstance(channels, int | np.integer) and isinstance(gain, int)
                                             and not isinstance(gain, bool)) else None
        plan = self._scan_plans.get(key) if key is not None else None
        if plan is None:
            chans, last = self._scan_channels(channels)
            gains = self._scan_gains(gain)
            plan = _ScanPlan(chans, last, gains)
            if key is not None:
                self._scan_plans[key] = plan
        return plan

    def _run_scan(self, plan: _ScanPlan) -> np.ndarray:
        """Configure (if needed), start, wait, and block-read the buffer: codes of 0..last."""
        last = plan.last
        self._configure_scan(last, plan.gains)
        self.win.write_offset(_CSR_LOW, _B["SCAN"], Width.D8)
        self._wait(last + 1, plan.what)
        words = self.bus.read_block(self.win.base + ADC_BUFFER_OFFSET, last + 1, space=self.win.am, width=Width.D16)
        return np.asarray(words, dtype=np.int64) & 0xFFF

    def _scan_channels(self, channels: int | Sequence[int]) -> tuple[list[int], int]:
        if isinstance(channels, int | np.integer):
            self._check_channel(int(channels))
            chans = list(range(int(channels) + 1))
        else:
            chans = [int(c) for c in channels]
            if not chans:
                raise ValueError("scan needs at least one channel")
            for c in chans:
                self._check_channel(c)
        return chans, max(chans)

    @staticmethod
    def _scan_gains(gain: int | Mapping[int, int]) -> list[int]:
        if isinstance(gain, Mapping):
            g = [1] * ADC_CHANNELS
            for ch, v in gain.items():
                AdcDriver._check_channel(int(ch))
                g[int(ch)] = check_gain(v)
            return g
        return [check_gain(gain)] * ADC_CHANNELS

    def _configure_scan(self, last: int, gains: list[int]) -> None:
        cfg = (last, *_scan_gain_words(tuple(gains)))
        if cfg == self._scan_cfg:
            return  # registers already hold it: save three bus cycles per tick
        self.win.write("SCAN_LAST", last)
        self.win.write("SCAN_GAIN0", cfg[1])
        self.win.write("SCAN_GAIN1", cfg[2])
        self._scan_cfg = cfg

    # --- waiting ----------------------------------------------------------------------------
    def _wait(self, conversions: int, what: str) -> None:
        nominal = conversions * self.conversion_time_s
        deadline = self.bus.now() + nominal + self.timeout_s
        if self._vector is not None:
            seen = self._irq_count
            self.bus.delay(nominal)
            while self._irq_count == seen:
                if self.bus.now() >= deadline:
                    raise AdcTimeoutError(f"{what} (interrupt-driven)", nominal + self.timeout_s,
                                          self.win.read("CSR"))
                self.bus.delay(self.poll_interval_s)
            return
        self.bus.delay(nominal)
        while True:
            csr = self.win.read_offset(_CSR_LOW, Width.D8)
            if csr & _B["DONE"] and not csr & _B["BUSY"]:
                return
            if self.bus.now() >= deadline:
                raise AdcTimeoutError(what, nominal + self.timeout_s, self.win.read("CSR"))
            self.bus.delay(self.poll_interval_s)

    @staticmethod
    def _check_channel(channel: int) -> None:
        if not 0 <= channel < ADC_CHANNELS:
            raise ValueError(f"ADC channel {channel} is not 0..{ADC_CHANNELS - 1}")


@functools.lru_cache(maxsize=64)
def _scan_gain_words(gains: tuple[int, ...]) -> tuple[int, int]:
    """SCAN_GAIN0 and SCAN_GAIN1 for 16 per-channel gains (computed once per gain list: a scan
    every tick would otherwise encode 16 gains each time)."""
    g0 = sum(gain_code(gains[i]) << (2 * i) for i in range(8))
    g1 = sum(gain_code(gains[8 + i]) << (2 * i) for i in range(8))
    return g0, g1


# --- lanes: one driver for the B boards of a bus of lanes (batched lockstep, issue #34) -----------
# A driver of lanes makes its scalar drivers' bus cycles once for every lane: the registers it
# reads hold a value per lane (hal.lanes). AdcDriver.from_lanes selects, once, the three steps
# that differ from the scalar code above (which runs unchanged on a scalar driver):
# * the block read of a scan's buffer gives a word per channel and lane: scan_counts returns codes
#   of shape (k, B), scan calibrated volts of shape (k, B) (each lane's column: the scalar driver's
#   (k,) operations, element by element, so the same bits);
# * the end-of-scan poll branches on the CSR each lane reads: the live lanes' common answer
#   (VmeBus.decide; a lane whose board said otherwise is ejected);
# * each lane keeps its scalar driver's calibration (arrays of shape (k, B) where the lanes'
#   calibrations differ, (k, 1) where they are alike).
# Out of scope (NotImplementedError): interrupt-driven waits (their instances run scalar).

def _stack_adc_drivers(cls: type[AdcDriver], drivers: Sequence[AdcDriver], bus: VmeBus) -> AdcDriver:
    """:meth:`AdcDriver.from_lanes`: one driver for ``drivers`` (one per lane, in lane order)."""
    lanes = bus.lanes
    if lanes is None:
        raise ValueError("AdcDriver.from_lanes needs a bus of lanes (its .lanes is a hal.lanes.LaneSet)")
    if len(drivers) != lanes.size:
        raise ValueError(f"{len(drivers)} ADC drivers for a bus of {lanes.size} lanes")
    first = drivers[0]

    def same(d: AdcDriver) -> tuple[object, ...]:
        return (d.win.base, d.win.am, d.range, d._config, d._scan_cfg, d.conversion_time_s, d.poll_interval_s,
                d.timeout_s)

    for d in drivers:
        if type(d) is not cls:
            raise NotImplementedError(f"a {type(d).__name__} is not a {cls.__name__}; it cannot stack with one")
        if d._vector is not None:
            raise NotImplementedError(f"ADC at 0x{d.win.base:X}: interrupt-driven waits cannot run in lanes")
        if same(d) != same(first):
            raise NotImplementedError(f"ADC at 0x{d.win.base:X}: drivers that differ in address, range, scan "
                                      "set-up or timing cannot run in lanes")
    drv = cls.__new__(cls)
    drv.bus = bus
    drv.win = BoardWindow(bus, first.win.base, ADC_REGMAP, first.win.am)
    drv.calibration = first.calibration
    drv.conversion_time_s, drv.poll_interval_s, drv.timeout_s = (first.conversion_time_s, first.poll_interval_s,
                                                                 first.timeout_s)
    drv._vector = None
    drv._irq_count = stack([d._irq_count for d in drivers])
    drv._scan_cfg = first._scan_cfg
    drv._scan_plans = {}
    drv.range, drv._config = first.range, first._config
    ls = _AdcDriverLanes(drv, [d.calibration for d in drivers], lanes)
    drv._lanes = ls
    # the lane-mode steps, selected once (the scalar methods run unchanged on a scalar driver)
    drv.scan = ls.scan  # type: ignore[method-assign]
    drv._run_scan = ls.run_scan  # type: ignore[method-assign]
    drv._wait = ls.wait  # type: ignore[method-assign]
    return drv


class _AdcDriverLanes:
    """The per-lane part of a driver of lanes, and its lane-mode steps."""

    def __init__(self, driver: AdcDriver, calibrations: Sequence[Calibration], lanes: LaneSet) -> None:
        self.driver, self.lanes, self.n = driver, lanes, lanes.size
        #: each lane's calibration (lane order)
        self.calibrations = tuple(calibrations)

    def scan(self, channels: int | Sequence[int], gain: int | Mapping[int, int] = 1) -> np.ndarray:
        """:meth:`AdcDriver.scan` of every lane: calibrated volts, shape (k, B)."""
        d = self.driver
        plan = d._scan_plan(channels, gain)
        codes = self.run_scan(plan)[plan.chans]
        if plan.cal is not d.calibration or plan.range is not d.range:
            self.bind(plan)
        # the scalar scan's operations, element by element (each lane's arrays broadcast on its column)
        volts = plan.v0 + codes * plan.lsb if plan.bipolar else codes * plan.lsb
        return (volts - plan.offset_v) / plan.cal_gain  # type: ignore[no-any-return]

    def bind(self, plan: _ScanPlan) -> None:
        """:meth:`_ScanPlan.bind` for lanes: the conversion arrays as (k, 1) columns, the
        calibration's (k, B) where the lanes' calibrations differ. A calibration assigned to the
        driver of lanes (``driver.calibration = cal``) is every lane's from then on."""
        d = self.driver
        if d.calibration is not self.calibrations[0]:
            self.calibrations = (d.calibration,) * self.n
        plan.bind(d.calibration, d.range)
        plan.v0, plan.lsb = plan.v0[:, None], plan.lsb[:, None]
        for name, field in (("offset_v", "offset_v"), ("cal_gain", "gain")):
            per_lane = stack([np.asarray(getattr(c, field), dtype=float)[plan.chans] for c in self.calibrations])
            setattr(plan, name, per_lane if per_lane.ndim == 2 else per_lane[:, None])

    def run_scan(self, plan: _ScanPlan) -> np.ndarray:
        """:meth:`AdcDriver._run_scan` of every lane: codes of channels 0..last, shape (last+1, B)."""
        d = self.driver
        last = plan.last
        d._configure_scan(last, plan.gains)
        d.win.write_offset(_CSR_LOW, _B["SCAN"], Width.D8)
        self.wait(last + 1, plan.what)
        words = d.bus.read_block(d.win.base + ADC_BUFFER_OFFSET, last + 1, space=d.win.am, width=Width.D16)
        codes = np.empty((last + 1, self.n), dtype=np.int64)
        for k, w in enumerate(words):  # a word every lane holds alike is one int
            codes[k] = w
        return codes & 0xFFF

    def wait(self, conversions: int, what: str) -> None:
        """:meth:`AdcDriver._wait` (polled) of every lane: one clock, so one poll sequence; the
        CSR each poll reads decides for the live lanes together (``VmeBus.decide``)."""
        d = self.driver
        if d._vector is not None:
            raise NotImplementedError("interrupt-driven ADC waits cannot run in lanes")
        bus = d.bus
        nominal = conversions * d.conversion_time_s
        deadline = bus.now() + nominal + d.timeout_s
        bus.delay(nominal)
        while True:
            csr = d.win.read_offset(_CSR_LOW, Width.D8)
            done = (csr & (_B["DONE"] | _B["BUSY"])) == _B["DONE"]  # the scalar poll's condition
            if bus.decide(done, f"ADC {what}: done in some lanes, busy in others"):
                return
            if bus.now() >= deadline:
                first_live = int(np.argmax(self.lanes.alive))
                raise AdcTimeoutError(what, nominal + d.timeout_s, int(lane(d.win.read("CSR"), first_live)))
            bus.delay(d.poll_interval_s)
