"""The quadrature decoder's doc (docs/boards/quadrature.md) is its spec: the driver's register map
and the emulator's own declaration are each checked against the doc's table, never against each
other; the doc's worked conversion examples are checked as literals."""

from __future__ import annotations

import math

import pytest

from emulators.crate import Crate
from emulators.quadrature import BOARD_MAP, QuadratureBoard
from emulators.signals import QuadratureEvents
from hal.quadrature import QUAD_REGS, CountJumpError, IndexNotSeenError, QuadratureDriver
from hal.vme import BusError, BusErrorCause, Width
from tests.support.board_spec import doc_registers, map_differences

BASE = 0x5000


@pytest.fixture(scope="module")
def doc():
    return doc_registers("quadrature")


def test_the_doc_states_every_register_of_the_board(doc) -> None:
    # two globals and eleven registers in each of four channel blocks
    assert len(doc) == 2 + 4 * 11
    assert (doc["ID"].offset, doc["ID"].reset) == (0x00, 0x5101)
    assert doc["CH3_PRE_LO"].offset == 0x96


def test_the_drivers_register_map_is_the_docs_table(doc) -> None:
    assert map_differences(QUAD_REGS, doc, who="driver") == []
    assert QUAD_REGS.size == 0xA0 and QUAD_REGS.space.name == "A16"


def test_the_emulators_own_register_map_is_the_docs_table(doc) -> None:
    assert map_differences(BOARD_MAP, doc, who="emulator") == []
    assert BOARD_MAP.size == 0xA0 and BOARD_MAP.space.name == "A16"


def _board() -> tuple[Crate, QuadratureBoard]:
    c = Crate("quad-doc")
    b = QuadratureBoard("quad0", nets={0: "enc0"})
    c.install(b, base=BASE, space="A16", slot=5)
    return c, b


@pytest.mark.parametrize("offset", [0x04, 0x1E, 0x26, 0x38, 0x3E, 0x46, 0x98, 0x9E])
def test_holes_in_the_map_end_in_berr_no_responder(offset: int) -> None:
    c, _ = _board()
    with pytest.raises(BusError) as ei:
        c.read(BASE + offset, space="A16", width=Width.D16)
    assert ei.value.cause is BusErrorCause.NO_RESPONDER


def test_reset_values_are_the_docs_reset_column() -> None:
    c, _ = _board()
    # ID, then channel 2's CTL, STATUS, OL_HI/LO, CNT_HI/LO, IDX_HI/LO, PRE_HI/LO
    got = [c.read(BASE + o, space="A16", width=Width.D16)
           for o in (0x00, 0x60, 0x64, 0x68, 0x6A, 0x6C, 0x6E, 0x70, 0x72, 0x74, 0x76)]
    assert got == [0x5101, 0x0002] + [0x0000] * 9


def test_d8_reads_of_a_24_bit_value_are_its_three_bytes_and_a_zero() -> None:
    c, _ = _board()
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=0x123456))
    c.write(BASE + 0x22, 0x0001, space="A16", width=Width.D16)  # CH0 LATCH
    assert [c.read(BASE + o, space="A16", width=Width.D8) for o in (0x28, 0x29, 0x2A, 0x2B)] == [0x00, 0x12, 0x34, 0x56]
    assert [c.read(BASE + o, space="A16", width=Width.D8) for o in (0x00, 0x01)] == [0x51, 0x01]


def test_a_d8_write_changes_only_its_byte() -> None:
    c, _ = _board()
    c.write(BASE + 0x36, 0xABCD, space="A16", width=Width.D16)  # CH0 PRE_LO
    c.write(BASE + 0x37, 0xEF, space="A16", width=Width.D8)  # its low byte only
    assert c.read(BASE + 0x36, space="A16", width=Width.D16) == 0xABEF
    c.write(BASE + 0x20, 0x0011, space="A16", width=Width.D16)  # CH0 CTL: x2, armed
    c.write(BASE + 0x20, 0xFF, space="A16", width=Width.D8)  # the unused high byte
    assert c.read(BASE + 0x20, space="A16", width=Width.D16) == 0x0011


# --- the doc's worked examples ("Data formats and conversions"), as literals ---------------
def _driver(counts_per_rev: float = 2000.0) -> tuple[Crate, QuadratureDriver]:
    c, _ = _board()
    return c, QuadratureDriver(c, BASE, counts_per_rev=counts_per_rev, channels=(0,))


def test_counts_in_x4_x2_x1_and_floor_prescaling_below_zero() -> None:
    for mode, after_10, after_minus_1 in ((4, 10, 0xFFFFFF), (2, 5, 0xFFFFFF), (1, 2, 0xFFFFFF)):
        c, d = _driver()
        d.set_mode(0, mode)
        c.signals.publish_quadrature("enc0", QuadratureEvents(counts=10))
        assert d.read_count(0) == after_10
        c, d = _driver()
        d.set_mode(0, mode)
        c.signals.publish_quadrature("enc0", QuadratureEvents(counts=-1))
        assert d.read_count(0) == after_minus_1


def test_angle_of_a_500_line_encoder_in_x4_and_x1() -> None:
    c, d = _driver(2000.0)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=500))
    assert d.position_rad(0) == pytest.approx(1.5707963, abs=1e-7)  # π/2
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=1))
    assert d.position_rad(0) - 1.5707963 == pytest.approx(0.0031416, abs=1e-7)  # one count: 3.1416 mrad
    c, d = _driver(2000.0)
    d.set_mode(0, 1)
    assert d.counts_per_rev(0) == 500.0
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=2000))  # 500 x1 counts
    assert d.position_rad(0) == pytest.approx(6.2831853, abs=1e-7)  # 2π


def test_velocity_of_40_counts_per_8_ms_tick() -> None:
    c, d = _driver(2000.0)
    d.update(0.008)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=40))
    r = d.update(0.008)[0]
    assert r.velocity_counts_s == pytest.approx(5000.0)
    assert r.velocity_rad_s == pytest.approx(15.70796, abs=1e-5)
    assert math.isclose(r.position_rad, 0.1256637, abs_tol=1e-7)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=40))
    assert d.velocity(0, 0.008) == pytest.approx(15.70796, abs=1e-5)  # the one-channel read, same tick rule


def test_velocity_estimator_edges() -> None:
    # the first tick has no previous count: 0; |Δ| equal to low_speed_counts (4) is Δ/dt
    c, d = _driver(2000.0)
    assert d.update(0.008)[0].velocity_counts_s == 0.0
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=4))
    assert d.update(0.008)[0].velocity_counts_s == pytest.approx(500.0)
    # |Δ| equal to max_counts_per_tick is allowed; one more is a CountJumpError
    c, _ = _board()
    d = QuadratureDriver(c, BASE, counts_per_rev=2000.0, channels=(0,), max_counts_per_tick=100)
    d.update(0.008)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=100))
    assert d.update(0.008)[0].velocity_counts_s == pytest.approx(12500.0)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=-101))
    with pytest.raises(CountJumpError):
        d.update(0.008)
    # no count for stop_ticks (3) ticks: 0; before that at most one count per elapsed time
    c, _ = _board()
    d = QuadratureDriver(c, BASE, counts_per_rev=2000.0, channels=(0,), stop_ticks=3)
    d.update(0.008)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=1))
    v = [d.update(0.008)[0].velocity_counts_s for _ in range(4)]
    assert v == pytest.approx([125.0, 125.0, 62.5, 0.0])  # 1/(m·dt) for m = 1, 1, 2 ticks; then 0


def test_velocity_at_rest_and_the_low_speed_threshold_after_a_pause() -> None:
    c, d = _driver(2000.0)
    assert [d.update(0.008)[0].velocity_counts_s for _ in range(3)] == [0.0, 0.0, 0.0]
    # two ticks without a count, then 4 counts (= low_speed_counts): Δ/dt, not 4 counts over 3 ticks
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=4))
    assert d.update(0.008)[0].velocity_counts_s == pytest.approx(500.0)


def test_driver_defaults_and_limits_from_the_api() -> None:
    c, _ = _board()
    d = QuadratureDriver(c, BASE, counts_per_rev=0.5, channels=(0,))  # any counts_per_rev > 0
    assert (d.low_speed_counts, d.stop_ticks, d.max_counts_per_tick) == (4, 125, None)
    d = QuadratureDriver(c, BASE, counts_per_rev=2000.0, channels=(0,), low_speed_counts=0, stop_ticks=0)
    assert (d.low_speed_counts, d.stop_ticks) == (1, 1)


def test_preset_and_mode_change_keep_home_and_velocity_consistent() -> None:
    c, _ = _board()
    d = QuadratureDriver(c, BASE, counts_per_rev=2000.0, channels=(0,), max_counts_per_tick=50)
    d.arm_index(0)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=30, index_offsets=(10,)))
    assert d.home_at_index(0) == 10
    d.update(0.008)
    d.preset(0, 0x400000)  # the counter jumps; the home and the velocity's last count move with it
    assert d.position_counts(0) == 0x400000  # the unwrapped count jumps with the counter
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=10))
    assert d.update(0.008)[0].velocity_counts_s == pytest.approx(1250.0)  # 10 counts, not a jump
    # one revolution after the homed index (at 10, now at 40): the next index 1970 counts on
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=1990, index_offsets=(1970,)))
    assert d.check_index(0) == 0.0
    d.set_mode(0, 2)
    with pytest.raises(IndexNotSeenError, match=r"^quadrature channel 0: the axis is not homed; call "
                                                r"home_at_index\(\) first$") as ei:  # the grid was in x4 counts
        d.check_index(0)
    assert ei.value.channel == 0
    assert d.update(0.008)[0].velocity_counts_s == 0.0  # the estimator restarts in the new mode


def test_update_reports_the_position_from_the_zero() -> None:
    c, d = _driver(2000.0)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=100))
    d.set_zero(0, 1.0)
    c.signals.publish_quadrature("enc0", QuadratureEvents(counts=500))
    assert d.update(0.008)[0].position_rad == pytest.approx(1.0 + 1.5707963, abs=1e-7)  # + 500 counts = π/2
    d.set_zero(0)  # by default the current position becomes 0 rad
    assert d.position_rad(0) == 0.0
