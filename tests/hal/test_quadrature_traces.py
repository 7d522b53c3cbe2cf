"""Golden bus traces of the quadrature driver: every cycle of each operation, written out by hand
from docs/boards/quadrature.md ("Registers", "Driver cycles"), compared with what the driver does
on a recording bus — scripted (the driver alone) or forwarding to a crate with the emulator.

Board at A16 0x5000: ID 0x5000, GCMD 0x5002; channel 0's block at 0x5020 (CTL +0, CMD +2,
STATUS +4, OL_HI +8, OL_LO +A, CNT_HI +C, CNT_LO +E, IDX_HI +10, IDX_LO +12, PRE_HI +14,
PRE_LO +16), channel 2's at 0x5060. STATUS bits: index 0x1, illegal 0x2, overflow 0x4,
underflow 0x8, A 0x100, B 0x200.
"""

from __future__ import annotations

import contextlib

import pytest

from emulators.crate import Crate
from emulators.quadrature import QuadratureBoard
from emulators.signals import QuadratureEvents
from hal.quadrature import IllegalTransitionError, IndexMismatchError, QuadratureDriver, TrackingLostError
from hal.vme import BoardIdError
from tests.support.bus_trace import RecordingBus

BASE = 0x5000
CPR = 2000.0


def _scripted(answers: dict[int, object], channels=(0,), **kw) -> tuple[RecordingBus, QuadratureDriver]:
    """A driver on a scripted bus; ``answers`` by address. Construction's cycles are checked in
    their own test and forgotten here."""
    bus = RecordingBus(answers={("A16", a): v for a, v in answers.items()})  # type: ignore[misc]
    d = QuadratureDriver(bus, BASE, counts_per_rev=CPR, channels=channels, **kw)
    bus.clear()
    return bus, d


def _emulated(channels=(0,)) -> tuple[Crate, RecordingBus, QuadratureBoard, QuadratureDriver]:
    crate = Crate("quad-trace")
    board = QuadratureBoard("quad0", nets={0: "enc0", 2: "enc2"})
    crate.install(board, base=BASE, space="A16", slot=5)
    bus = RecordingBus(crate)
    d = QuadratureDriver(bus, BASE, counts_per_rev=CPR, channels=channels)
    bus.clear()
    return crate, bus, board, d


# --- probe and reset ------------------------------------------------------------------------
def test_probe_reads_the_id_register_and_returns_the_revision() -> None:
    bus, d = _scripted({0x5000: 0x5101, 0x5028: 0, 0x502A: 0, 0x5020: 0x0002})
    assert d.probe() == 0x01
    assert bus.trace() == ["R A16 0x5000 D16 0x5101"]


def test_probe_of_another_board_is_a_board_id_error() -> None:
    _, d = _scripted({0x5000: 0xAD16, 0x5028: 0, 0x502A: 0, 0x5020: 0x0002})
    with pytest.raises(BoardIdError, match="0xAD16"):
        d.probe()


def test_construction_latches_reads_each_channel_and_clears_its_wrap_flags() -> None:
    bus = RecordingBus(answers={
        ("A16", 0x5028): 0x00FF, ("A16", 0x502A): 0xFFFE, ("A16", 0x5020): 0x0002,  # channel 0
        ("A16", 0x5068): 0x0080, ("A16", 0x506A): 0x0000, ("A16", 0x5060): 0x0000,  # channel 2: x1
        ("A16", 0x5024): 0x0000, ("A16", 0x5064): 0x0000,
    })
    d = QuadratureDriver(bus, BASE, counts_per_rev=CPR, channels=(2, 0))
    assert bus.trace() == [
        "W A16 0x5022 D16 0x0001", "R A16 0x5028 D16 0x00FF", "R A16 0x502A D16 0xFFFE",
        "R A16 0x5020 D16 0x0002", "W A16 0x5024 D16 0x000C",
        "W A16 0x5062 D16 0x0001", "R A16 0x5068 D16 0x0080", "R A16 0x506A D16 0x0000",
        "R A16 0x5060 D16 0x0000", "W A16 0x5064 D16 0x000C",
    ]
    assert d.counts_per_rev(0) == 2000.0 and d.counts_per_rev(2) == 500.0  # x4 and x1 read from CTL
    # the first value is sign-extended from 24 bits: 0xFFFFFE → −2, 0x800000 → −8 388 608
    assert (d.position_counts(0), d.position_counts(2)) == (-2, -8_388_608)
    # until homed the zero is count 0: −2 counts of 2000 per revolution = −6.2832 mrad
    assert d.position_rad(0) == pytest.approx(-0.0062832, abs=1e-7)


# --- latch and read, across a wrap ---------------------------------------------------------
def test_read_count_latches_then_reads_high_and_low() -> None:
    bus, d = _scripted({0x5028: [0x0000, 0x0012], 0x502A: [0x0000, 0x3456], 0x5020: 0x0002})
    assert d.read_count(0) == 0x123456
    assert bus.trace() == ["W A16 0x5022 D16 0x0001", "R A16 0x5028 D16 0x0012", "R A16 0x502A D16 0x3456"]


def test_unlatched_read_reads_the_live_counter_high_then_low() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x502C: 0x0001, 0x502E: 0x0000})
    assert d.read_count_unlatched(0) == 0x010000
    assert bus.trace() == ["R A16 0x502C D16 0x0001", "R A16 0x502E D16 0x0000"]


def test_update_across_the_top_of_the_counter_consumes_overflow() -> None:
    # 0xFFFFF0 (−16) → 0x000010 with OVERFLOW: +32 counts
    bus, d = _scripted({0x5028: [0x00FF, 0x0000], 0x502A: [0xFFF0, 0x0010], 0x5020: 0x0002, 0x5024: 0x0004})
    r = d.update(0.008)[0]
    assert bus.trace() == [
        "W A16 0x5002 D16 0x0001",
        "R A16 0x5024 D16 0x0004", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0010",
        "W A16 0x5024 D16 0x0004",
    ]
    assert (r.raw, r.counts) == (0x000010, 16)


def test_position_read_across_zero_consumes_underflow() -> None:
    # 0x000005 → 0xFFFFFB with UNDERFLOW: −10 counts
    bus, d = _scripted({0x5028: [0x0000, 0x00FF], 0x502A: [0x0005, 0xFFFB], 0x5020: 0x0002, 0x5024: 0x0008})
    assert d.position_counts(0) == -5
    assert bus.trace() == [
        "W A16 0x5022 D16 0x0001", "R A16 0x5024 D16 0x0008", "R A16 0x5028 D16 0x00FF",
        "R A16 0x502A D16 0xFFFB", "W A16 0x5024 D16 0x0008",
    ]


def test_update_latches_every_channel_in_one_gcmd_write() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: [0x0000, 0x0007], 0x5020: 0x0002, 0x5024: 0x0000,
                        0x5068: 0, 0x506A: [0x0000, 0x0003], 0x5060: 0x0002, 0x5064: 0x0000}, channels=(0, 2))
    r = d.update(0.008)
    assert bus.trace() == [
        "W A16 0x5002 D16 0x0005",
        "R A16 0x5024 D16 0x0000", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0007", "W A16 0x5024 D16 0x0000",
        "R A16 0x5064 D16 0x0000", "R A16 0x5068 D16 0x0000", "R A16 0x506A D16 0x0003", "W A16 0x5064 D16 0x0000",
    ]
    assert (r[0].counts, r[2].counts) == (7, 3)


def test_more_than_a_quarter_range_through_the_top_needs_overflow() -> None:
    # 0xC00000 (−4 194 304) → 0x300000 is +7 340 032 through the top: accepted with OVERFLOW ...
    answers = {0x5028: [0x00C0, 0x0030], 0x502A: [0x0000, 0x0000], 0x5020: 0x0002}
    _, d = _scripted({**answers, 0x5024: 0x0004})
    assert d.position_counts(0) == 3_145_728
    # ... and tracking is lost without it (or with UNDERFLOW instead); it goes on from the new value
    for status in (0x0000, 0x0008):
        _, d = _scripted({**answers, 0x5024: status})
        with pytest.raises(TrackingLostError) as ei:
            d.update(0.008)
        assert ei.value.channel == 0
        assert d.position_counts(0) == 3_145_728


def test_more_than_a_quarter_range_through_zero_needs_underflow() -> None:
    # 0x300000 → 0xC00000 is −7 340 032 through zero
    answers = {0x5028: [0x0030, 0x00C0], 0x502A: 0x0000, 0x5020: 0x0002}
    _, d = _scripted({**answers, 0x5024: 0x0008})
    assert d.position_counts(0) == 3_145_728 - 7_340_032
    for status in (0x0000, 0x0004):
        _, d = _scripted({**answers, 0x5024: status})
        with pytest.raises(TrackingLostError):
            d.position_counts(0)


@pytest.mark.parametrize("old,new,delta", [
    (0x000000, 0x400000, 0x400000),  # exactly a quarter range through the top: no flag needed
    (0x900000, 0xFFFFFF, 0x6FFFFF),  # up to 0xFFFFFF, not through it
    (0x700000, 0x000000, -0x700000),  # down to 0, not through it
    (0xD00000, 0x100000, 0x400000),  # a quarter range through the top, no flag
])
def test_moves_that_need_no_wrap_flag(old: int, new: int, delta: int) -> None:
    _, d = _scripted({0x5028: [old >> 16, new >> 16], 0x502A: [old & 0xFFFF, new & 0xFFFF], 0x5020: 0x0002,
                      0x5024: 0x0000})
    first = old - (1 << 24) if old >= 0x800000 else old
    assert d.position_counts(0) == first + delta


def test_illegal_status_raises_from_a_position_or_velocity_read() -> None:
    _, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0002})
    for read in (lambda: d.position_counts(0), lambda: d.velocity(0, 0.008)):
        with pytest.raises(IllegalTransitionError) as ei:
            read()
        assert ei.value.channel == 0


def test_latch_and_read_across_a_wrap_on_the_emulated_board() -> None:
    crate, bus, _, d = _emulated()
    d.preset(0, 0xFFFFF0)
    bus.clear()
    crate.signals.publish_quadrature("enc0", QuadratureEvents(counts=40, phase=2))
    r = d.update(0.008)[0]
    assert bus.trace() == [
        "W A16 0x5002 D16 0x0001",
        "R A16 0x5024 D16 0x0304", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0018",
        "W A16 0x5024 D16 0x0004",
    ]
    assert (r.raw, r.counts, r.status.a, r.status.b, r.status.overflow) == (0x18, 24, True, True, True)


# --- index -----------------------------------------------------------------------------
def test_arm_index_clears_the_flag_then_sets_the_arm_bit_keeping_the_mode() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0001})  # x2
    d.arm_index(0)
    assert bus.trace() == ["W A16 0x5024 D16 0x0001", "R A16 0x5020 D16 0x0001", "W A16 0x5020 D16 0x0011"]


def test_home_at_index_across_a_wrap_reads_the_index_latch_and_rearms() -> None:
    # start at 0xFFFFF0 (−16); now 0x000010 (+16, OVERFLOW); index latched at 0xFFFFF8 (−8)
    bus, d = _scripted({0x5028: [0x00FF, 0x0000], 0x502A: [0xFFF0, 0x0010], 0x5020: 0x0002,
                        0x5024: [0x0001, 0x0005], 0x5030: 0x00FF, 0x5032: 0xFFF8})
    assert d.home_at_index(0) == -8
    assert bus.trace() == [
        "R A16 0x5024 D16 0x0001",
        "W A16 0x5022 D16 0x0001", "R A16 0x5024 D16 0x0005", "R A16 0x5028 D16 0x0000",
        "R A16 0x502A D16 0x0010", "W A16 0x5024 D16 0x0004",
        "R A16 0x5030 D16 0x00FF", "R A16 0x5032 D16 0xFFF8",
        "W A16 0x5024 D16 0x0001", "R A16 0x5020 D16 0x0002", "W A16 0x5020 D16 0x0012",
    ]
    assert bus.cycles[-1].value & 0x10  # re-armed


def test_check_index_without_a_capture_reads_status_only() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: [0x0001, 0x0001, 0x0000],
                        0x5030: 0x0000, 0x5032: 0x0000})
    d.home_at_index(0)
    bus.clear()
    assert d.check_index(0) is None
    assert bus.trace() == ["R A16 0x5024 D16 0x0000"]


def test_index_pulse_across_a_wrap_on_the_emulated_board() -> None:
    crate, bus, _, d = _emulated()
    d.preset(0, 0xFFFFF0)  # −16
    bus.clear()
    d.arm_index(0)
    # 40 counts; the index pulse at the 10th: IDX = 0xFFFFF0 + 10 = 0xFFFFFA, counter 0x000018
    crate.signals.publish_quadrature("enc0", QuadratureEvents(counts=40, index_offsets=(10,)))
    assert d.home_at_index(0) == -6
    assert bus.trace() == [
        "W A16 0x5024 D16 0x0001", "R A16 0x5020 D16 0x0002", "W A16 0x5020 D16 0x0012",
        "R A16 0x5024 D16 0x0005",
        "W A16 0x5022 D16 0x0001", "R A16 0x5024 D16 0x0005", "R A16 0x5028 D16 0x0000",
        "R A16 0x502A D16 0x0018", "W A16 0x5024 D16 0x0004",
        "R A16 0x5030 D16 0x00FF", "R A16 0x5032 D16 0xFFFA",
        "W A16 0x5024 D16 0x0001", "R A16 0x5020 D16 0x0002", "W A16 0x5020 D16 0x0012",
    ]
    assert d.position_rad(0) == pytest.approx(30 * 6.283185307 / 2000)


# --- illegal transitions ------------------------------------------------------------------
def test_illegal_status_raises_after_reading_every_channel_and_rereads_status() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0302}, channels=(0,))
    with pytest.raises(IllegalTransitionError) as ei:
        d.update(0.008)
    assert bus.trace() == [
        "W A16 0x5002 D16 0x0001",
        "R A16 0x5024 D16 0x0302", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0000",
        "W A16 0x5024 D16 0x0000", "R A16 0x5024 D16 0x0302",
    ]
    st = ei.value.readings[0].status
    assert (st.illegal, st.a, st.b, st.index, st.overflow, st.underflow) == (True, True, True, False, False, False)


def test_report_mode_reads_the_illegal_status_once() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0102}, errors="report")
    st = d.update(0.008)[0].status
    assert bus.trace() == [
        "W A16 0x5002 D16 0x0001",
        "R A16 0x5024 D16 0x0102", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0000",
        "W A16 0x5024 D16 0x0000",
    ]
    assert (st.illegal, st.a, st.b) == (True, True, False)


def test_status_and_clear_errors() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x020A})
    st = d.status(0)
    d.clear_errors(0)
    assert bus.trace() == ["R A16 0x5024 D16 0x020A", "W A16 0x5024 D16 0x000E"]
    assert (st.underflow, st.illegal, st.b, st.a, st.overflow, st.index) == (True, True, True, False, False, False)


def test_clear_illegal_writes_the_illegal_bit_alone() -> None:
    # docs/boards/quadrature.md: `clear_illegal(n)` — W STATUS 0x0002 (channel 0's STATUS at +0x24)
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0000})
    d.clear_illegal(0)
    assert bus.trace() == ["W A16 0x5024 D16 0x0002"]


def test_illegal_transition_on_the_emulated_board_is_sticky_until_cleared() -> None:
    crate, bus, _, d = _emulated()
    crate.signals.publish_quadrature("enc0", QuadratureEvents(counts=0, illegal=3, phase=1))
    for _ in range(2):
        with pytest.raises(IllegalTransitionError):
            d.update(0.008)
    d.clear_errors(0)
    assert not d.update(0.008)[0].status.illegal
    assert bus.trace()[:6] == [
        "W A16 0x5002 D16 0x0001",
        "R A16 0x5024 D16 0x0102", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0000",
        "W A16 0x5024 D16 0x0000", "R A16 0x5024 D16 0x0102",
    ]
    assert bus.trace()[12:14] == ["W A16 0x5024 D16 0x000E", "W A16 0x5002 D16 0x0001"]
    assert bus.trace()[14] == "R A16 0x5024 D16 0x0100"


# --- the interrupt path: there is none -----------------------------------------------------
def test_the_board_never_interrupts_and_the_driver_registers_no_handler() -> None:
    crate, bus, board, d = _emulated()
    d.arm_index(0)
    for ev in (QuadratureEvents(counts=-5), QuadratureEvents(counts=3, illegal=2, index_offsets=(1,))):
        crate.signals.publish_quadrature("enc0", ev)
        with pytest.raises(IllegalTransitionError) if ev.illegal else contextlib.nullcontext():
            d.update(0.008)
    board.inject("counter_jump", channel=0, counts=1 << 23)
    assert not board.irq_pending
    assert all(bus.irq_handler(v) is None for v in range(256))


# --- modes, preset, clear -----------------------------------------------------------------
def test_preset_writes_high_then_low_then_latch_and_preset_together() -> None:
    bus, d = _scripted({0x5028: [0x0000, 0x0000], 0x502A: [0x0000, 0x0020], 0x5020: 0x0002})
    d.preset(0, 0xABCDEF)
    assert bus.trace() == [
        "W A16 0x5034 D16 0x00AB", "W A16 0x5036 D16 0xCDEF", "W A16 0x5022 D16 0x0005",
        "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0020", "W A16 0x5024 D16 0x000C",
    ]


def test_clear_latches_and_clears_in_one_command() -> None:
    bus, d = _scripted({0x5028: 0x0000, 0x502A: [0x0000, 0x0009], 0x5020: 0x0002})
    d.clear(0)
    assert bus.trace() == [
        "W A16 0x5022 D16 0x0003", "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0009", "W A16 0x5024 D16 0x000C",
    ]


@pytest.mark.parametrize("mode,ctl", [(1, 0x0000), (2, 0x0001), (4, 0x0002)])
def test_set_mode_writes_the_mode_code_keeping_the_arm_bit(mode: int, ctl: int) -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: [0x0002, 0x0013], 0x5024: 0x0000})
    d.set_mode(0, mode)
    assert bus.trace()[-2:] == ["R A16 0x5020 D16 0x0013", f"W A16 0x5020 D16 0x{ctl | 0x10:04X}"]
    assert bus.trace()[:4] == ["W A16 0x5022 D16 0x0001", "R A16 0x5024 D16 0x0000",
                               "R A16 0x5028 D16 0x0000", "R A16 0x502A D16 0x0000"]


def test_hold_writes_mode_3() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0012})
    d.hold(0)
    assert bus.trace() == ["R A16 0x5020 D16 0x0012", "W A16 0x5020 D16 0x0013"]


def test_check_index_compares_with_the_homed_grid_within_the_tolerance() -> None:
    # homed at IDX 100; the next capture at 2101 = 100 + 2000 (one revolution) + 1 count
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0001, 0x5030: 0x0000,
                        0x5032: [0x0064, 0x0835]})
    assert d.home_at_index(0, position_rad=1.0) == 100
    # the zero is 1 rad (318.31 counts) below the index: count 0 is at 1 − 100·2π/2000 rad
    assert d.position_rad(0) == pytest.approx(1.0 - 0.3141593, abs=1e-7)
    bus.clear()
    assert d.check_index(0, tolerance_counts=1) == 1.0
    assert bus.trace() == [
        "R A16 0x5024 D16 0x0001", "R A16 0x5024 D16 0x0001",
        "W A16 0x5022 D16 0x0001", "R A16 0x5024 D16 0x0001", "R A16 0x5028 D16 0x0000",
        "R A16 0x502A D16 0x0000", "R A16 0x5030 D16 0x0000", "R A16 0x5032 D16 0x0835",
        "W A16 0x5024 D16 0x0001", "R A16 0x5020 D16 0x0002", "W A16 0x5020 D16 0x0012",
    ]
    with pytest.raises(IndexMismatchError) as ei:
        d.check_index(0)  # the default tolerance is half a count
    assert (ei.value.channel, ei.value.error_counts) == (0, 1.0)


def test_channels_are_0_to_3_and_the_preset_24_bits() -> None:
    bus, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0002})
    for bad in (4, -1):
        with pytest.raises(ValueError, match="0..3"):
            d.status(bad)
    with pytest.raises(ValueError, match="0..3"):
        QuadratureDriver(bus, BASE, counts_per_rev=CPR, channels=(4,))
    d.preset(0, 0xFFFFFF)  # the largest 24-bit value is a preset
    assert bus.trace()[:2] == ["W A16 0x5034 D16 0x00FF", "W A16 0x5036 D16 0xFFFF"]
    with pytest.raises(ValueError):
        d.preset(0, 0x1000000)


def test_a_channel_found_in_hold_is_taken_as_x4_and_status_keeps_its_raw_value() -> None:
    _, d = _scripted({0x5028: 0, 0x502A: 0, 0x5020: 0x0003, 0x5024: 0x0309})
    assert d.counts_per_rev(0) == 2000.0
    st = d.status(0)
    assert (st.raw, st.index, st.underflow) == (0x0309, True, True)
    # +0x600000 without a crossing, OVERFLOW set: lost; an error outside update() carries no readings
    with pytest.raises(TrackingLostError) as ei:
        _, d2 = _scripted({0x5028: [0x0000, 0x0060], 0x502A: 0, 0x5020: 0x0002, 0x5024: 0x0004})
        d2.position_counts(0)
    assert ei.value.readings == {}
