"""The emulator's per-cycle fast paths keep their behaviour: the clock runs events exactly when
due (also at a cycle's end), "no fault armed" is a flag that follows inject/clear, the IRQ
arbiter's highest level follows the lines, the ADC's block-drawn noise is the per-sample
stream, and the CAN codec's small-array quantization is the array one, bit for bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from emulators.adc import AdcBoard
from emulators.can.codec import SignalSpec, shared_codec
from emulators.clock import SimClock
from emulators.crate import Crate
from emulators.irq import IrqController
from emulators.ram import RamBoard
from emulators.rng import rng_for
from hal.vme import Width


# --- the clock ---------------------------------------------------------------------------------
def test_an_event_runs_when_the_clock_reaches_its_time_and_not_before() -> None:
    clock, ran = SimClock(), []
    clock.schedule(100, lambda: ran.append(clock.now_ns))
    clock.advance_to(99)
    assert ran == [] and clock.now_ns == 99
    clock.advance(1)
    assert ran == [100] and clock.now_ns == 100
    clock.advance_to(500)  # nothing left: only the time moves
    assert ran == [100] and clock.now_ns == 500 and clock.pending() == 0


def test_events_scheduled_by_events_run_in_the_same_advance_in_time_order() -> None:
    clock, ran = SimClock(), []

    def first() -> None:
        ran.append(("first", clock.now_ns))
        clock.schedule_in(10, lambda: ran.append(("chained", clock.now_ns)))
        clock.schedule(5_000, lambda: ran.append(("late", clock.now_ns)))

    clock.schedule(100, first)
    clock.schedule(150, lambda: ran.append(("second", clock.now_ns)))
    clock.advance_to(1_000)
    assert ran == [("first", 100), ("chained", 110), ("second", 150)]
    assert clock.now_ns == 1_000 and clock.next_due_ns == 5_000
    clock.advance(3_999)
    assert ran[-1] == ("second", 150)
    clock.advance(1)
    assert ran[-1] == ("late", 5_000)


def test_an_event_that_raises_leaves_the_rest_queued_and_due() -> None:
    clock, ran = SimClock(), []

    def boom() -> None:
        raise RuntimeError("board model bug")

    clock.schedule(10, boom)
    clock.schedule(20, lambda: ran.append(clock.now_ns))
    with pytest.raises(RuntimeError):
        clock.advance_to(30)
    assert clock.next_due_ns == 20
    clock.advance_to(30)
    assert ran == [20] and clock.now_ns == 30


def test_a_cycle_that_ends_at_an_events_time_sees_the_event() -> None:
    """The board's data cycle ends at now + cycle time; an event due exactly then runs before
    the board answers, one due a nanosecond later does not."""
    crate = Crate("t")
    ram = crate.install(RamBoard("ram", 0x100), base=0x200000, space="A24")
    assert isinstance(ram, RamBoard)
    ns = ram.cycle_ns(Width.D16, False)

    def set_to(v: int) -> None:
        ram.mem[0x10:0x12] = v.to_bytes(2, "big")

    crate.clock.schedule(crate.clock.now_ns + ns, lambda: set_to(0x123))
    assert crate.read(0x200010, space="A24", width=Width.D16) == 0x123
    crate.clock.schedule(crate.clock.now_ns + ns + 1, lambda: set_to(0x456))
    assert crate.read(0x200010, space="A24", width=Width.D16) == 0x123
    assert crate.read(0x200010, space="A24", width=Width.D16) == 0x456


# --- faults ------------------------------------------------------------------------------------
def test_the_faulted_flag_follows_inject_and_clear() -> None:
    adc = AdcBoard("adc")
    assert not adc.faulted and adc.fault("stuck_channel") is None and not adc.removed
    adc.inject("stuck_channel", channel=3, code=7)
    adc.inject("removed")
    assert adc.faulted and adc.fault("stuck_channel") == {"channel": 3, "code": 7} and adc.removed
    adc.clear_fault("removed")
    assert adc.faulted and not adc.removed
    assert adc.sample(3, 1, bipolar=True) == 7
    adc.clear_fault("stuck_channel")
    assert not adc.faulted and adc.fault("stuck_channel") is None
    adc.inject("noise_burst", rms_v=0.1)
    adc.clear_fault()
    assert not adc.faulted and adc.active_faults == {}


# --- interrupts --------------------------------------------------------------------------------
class _Src:
    def __init__(self, name: str, slot: int) -> None:
        self.name, self.slot = name, slot

    def iack(self, level: int) -> int:
        return 0


def test_the_highest_asserted_level_follows_the_lines() -> None:
    irq = IrqController(lambda v: None)
    a, b = _Src("a", 2), _Src("b", 3)
    assert irq.highest == 0
    irq.assert_line(a, 3)
    irq.assert_line(b, 5)
    assert irq.highest == 5 == irq.highest_pending()
    irq.assert_line(b, 1)  # re-asserting moves the board to the new level
    assert irq.highest == 3
    irq.release_line(a)
    assert irq.highest == 1
    irq.release_line(b)
    assert irq.highest == 0


# --- ADC noise drawn in blocks -----------------------------------------------------------------
def test_block_drawn_adc_noise_is_the_per_sample_stream() -> None:
    """600 noisy conversions (more than one block of normals) give the codes of one
    ``standard_normal()`` per sample from the board's stream."""
    crate = Crate("n")
    adc = crate.install(AdcBoard("adc0", wiring={2: "in"}, noise_rms_v=0.02, seed=11), base=0x1000, space="A16")
    assert isinstance(adc, AdcBoard)
    crate.signals.set_analog("in", 1.2345)
    ref = rng_for(11, "adc0", "noise")
    for k in range(600):
        v = 1.2345 + math.sqrt(0.02**2) * float(ref.standard_normal())
        # docs/boards/adc.md: ±10 V/4 = ±2.5 V, offset binary, LSB 5 V/4096
        want = min(max(math.floor((v + 2.5) / (5.0 / 4096) + 0.5), 0), 0xFFF)
        assert adc.sample(2, 4, bipolar=True) == want, k


def test_an_adc_scan_fills_the_buffers_at_each_conversions_end() -> None:
    crate = Crate("s")
    adc = crate.install(AdcBoard("adc", wiring={c: f"n{c}" for c in range(4)}), base=0x1000, space="A16")
    assert isinstance(adc, AdcBoard)
    for c in range(4):
        crate.signals.set_analog(f"n{c}", c + 0.5)
    crate.write(0x1000 + 0x0A, 3)  # SCAN_LAST (docs/boards/adc.md)
    t0 = crate.clock.now_ns
    crate.write(0x1000 + 0x02, 1 << 1)  # CSR.SCAN
    t_start = crate.clock.now_ns  # the scan starts when the write cycle reaches the board
    buf = [0x20 + 2 * c for c in range(4)]  # BUF0..BUF3
    crate.clock.advance_to(t_start + 2 * adc.conversion_time_ns)
    words = [adc.regs[f"BUF{c}"] for c in range(4)]
    assert [w >> 12 for w in words[:2]] == [0, 1] and words[2] == words[3] == 0
    crate.clock.advance_to(t_start + 4 * adc.conversion_time_ns)
    codes = [crate.read(0x1000 + o, width=Width.D16) & 0xFFF for o in buf]
    # 0.5, 1.5, 2.5, 3.5 V at gain 1 on ±10 V: 0x800 + V/(20 V/4096) = 0x800 + 102.4, 307.2, 512, 716.8
    assert codes == [0x866, 0x933, 0xA00, 0xACD]
    assert adc.conversions == 4 and t_start > t0


# --- codec quantization ------------------------------------------------------------------------
def _array_quantize(spec: SignalSpec, values: np.ndarray) -> tuple[np.ndarray, int]:
    """The array path, as the codec always computed it."""
    v = np.asarray(values, dtype=float)
    bad = ~np.isfinite(v)
    r = np.round((np.where(bad, spec.offset, v) - spec.offset) / spec.scale)
    clipped = np.clip(r, spec.raw_min, spec.raw_max)
    return clipped.astype(np.int64), int(np.count_nonzero(bad | (clipped != r)))


def test_small_array_quantization_is_bit_identical_to_the_array_path() -> None:
    rng = np.random.default_rng(5)
    checked = 0
    for specs in shared_codec().specs.values():
        for spec in specs.values():
            if spec.is_float:
                continue
            lo = spec.raw_min * spec.scale + spec.offset
            hi = spec.raw_max * spec.scale + spec.offset
            pad = 0.2 * (hi - lo)
            for trial in range(60):
                n = int(rng.integers(0, 20))
                v = rng.uniform(lo - pad, hi + pad, n)
                if n and trial % 3 == 0:  # exact half-LSB points: round half to even
                    v = (rng.integers(int(spec.raw_min), int(spec.raw_max) + 1, n) + 0.5) * spec.scale + spec.offset
                if n and trial % 5 == 0:
                    v[0] = np.nan
                if n and trial % 7 == 0:
                    v[-1] = -np.inf
                if n and trial % 11 == 0:
                    v[n // 2] = 1e308
                with np.errstate(over="ignore"):  # 1e308 / a small scale overflows to inf
                    want, got = _array_quantize(spec, v), spec.quantize(v)
                assert got[0].dtype == want[0].dtype and got[0].shape == want[0].shape
                assert np.array_equal(got[0], want[0]) and got[1] == want[1], (spec.name, v)
                checked += 1
    assert checked > 500


# --- the ADC's inline conversion ---------------------------------------------------------------
ADC_REGMAP = AdcBoard.REGMAP  # the emulator's own map: inline and reference paths of one emulator


@pytest.mark.parametrize("csr_range", [0, 1])
def test_inline_conversions_give_the_codes_of_the_reference_path(csr_range: int) -> None:
    """Scans converted inline (no fault armed) and through ``AdcBoard.sample`` (an inert fault
    armed: a stuck channel that is not scanned) give the same codes, noise, gain codes, offsets,
    gain errors, clipping at both rails and a noise source included, conversion after conversion."""
    def scan_codes(arm_inert_fault: bool) -> list[list[int]]:
        crate = Crate("c")
        board = AdcBoard("adc0", wiring={c: f"n{c}" for c in range(8)}, noise_rms_v=0.003, seed=4,
                         offset_v=[0.001 * c for c in range(16)], gain_error=[0.0005 * (c - 4) for c in range(16)])
        adc = crate.install(board, base=0x1000, space="A16")
        assert isinstance(adc, AdcBoard)
        adc.add_noise_source(lambda: 0.002 if crate.signals.get_analog("n1") > 0 else 0.0)
        if arm_inert_fault:
            adc.inject("stuck_channel", channel=15, code=0)
        base, csr = 0x1000, ADC_REGMAP["CSR"]
        wr = lambda reg, v: crate.write(base + ADC_REGMAP[reg].offset, v, space="A16")  # noqa: E731
        wr("SCAN_GAIN0", 0b11_10_01_00_11_10_01_00)  # gains 1, 2, 4, 8, 1, 2, 4, 8
        wr("SCAN_LAST", 7)
        rng = np.random.default_rng(9)
        out = []
        for _ in range(40):
            for c in range(8):
                crate.signals.set_analog(f"n{c}", float(rng.uniform(-12.0, 12.0)))
            wr("CSR", csr.pack(SCAN=1, RANGE=csr_range))
            crate.clock.advance(200_000)
            out.append([crate.read(base + ADC_REGMAP[f"BUF{c}"].offset, space="A16") for c in range(8)])
        return out

    assert scan_codes(False) == scan_codes(True)
