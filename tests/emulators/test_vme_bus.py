"""VME bus semantics on the emulated crate: decode, widths, alignment, byte order, BERR, time."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.board import RegisterBoard
from emulators.crate import Crate
from emulators.ram import RamBoard
from hal.vme import (
    Access,
    AddressSpace,
    BusError,
    BusErrorCause,
    Register,
    RegisterMap,
    VmeConfigError,
    Width,
    am_for,
    decode_am,
)


@pytest.mark.parametrize(
    "space,base", [("A16", 0x1000), ("A24", 0x200000), ("A32", 0x80000000)]
)
def test_address_decode_in_every_space(crate: Crate, space: str, base: int) -> None:
    crate.write(base + 0x10, 0xBEEF, space=space, width=Width.D16)
    assert crate.read(base + 0x10, space=space, width=Width.D16) == 0xBEEF
    # the same offset in another space is a different (or no) board
    other = {"A16": "A24", "A24": "A32", "A32": "A16"}[space]
    with pytest.raises((BusError, ValueError)):  # BERR, or outside the other space
        crate.read(base + 0x10, space=other, width=Width.D16)


@pytest.mark.parametrize("code,space", [(0x29, "A16"), (0x2D, "A16"), (0x39, "A24"), (0x3D, "A24"),
                                        (0x09, "A32"), (0x0D, "A32"), (0x3B, "A24"), (0x0F, "A32")])
def test_address_modifier_codes_select_the_space(crate: Crate, code: int, space: str) -> None:
    am = decode_am(code)
    assert am.space is AddressSpace.parse(space)
    base = {"A16": 0x1000, "A24": 0x200000, "A32": 0x80000000}[space]
    crate.write(base, 0x12, space=code, width=Width.D8)
    assert crate.read(base, space=code, width=Width.D8) == 0x12


def test_unknown_address_modifier_is_rejected() -> None:
    with pytest.raises(ValueError, match="0x3C"):
        decode_am(0x3C)


@pytest.mark.parametrize("width", list(Width))
@pytest.mark.parametrize("offset", range(4))
def test_alignment_rules_for_every_width(crate: Crate, width: Width, offset: int) -> None:
    addr = 0x200000 + 0x20 + offset
    if offset % int(width):
        with pytest.raises(BusError) as ei:
            crate.read(addr, space="A24", width=width)
        assert ei.value.cause is BusErrorCause.MISALIGNED
        assert ei.value.address == addr and ei.value.width is width
    else:
        crate.write(addr, width.max_value, space="A24", width=width)
        assert crate.read(addr, space="A24", width=width) == width.max_value


def test_big_endian_d32_reads_back_as_four_d8(crate: Crate) -> None:
    crate.write(0x200100, 0x11223344, space="A24", width=Width.D32)
    assert [crate.read(0x200100 + i, space="A24", width=Width.D8) for i in range(4)] == [
        0x11, 0x22, 0x33, 0x44]
    assert crate.read(0x200100, space="A24", width=Width.D16) == 0x1122
    assert crate.read(0x200102, space="A24", width=Width.D16) == 0x3344


def test_unmapped_access_is_bus_error_not_zero(crate: Crate) -> None:
    t0 = crate.clock.now_ns
    with pytest.raises(BusError) as ei:
        crate.read(0x300000, space="A24", width=Width.D16)
    e = ei.value
    assert e.cause is BusErrorCause.NO_RESPONDER
    assert e.address == 0x300000 and e.am.space is AddressSpace.A24 and e.width is Width.D16
    assert "0x300000" in str(e) and "D16" in str(e)
    assert crate.clock.now_ns - t0 == crate.bus_timeout_ns  # BERR comes after the bus timeout
    assert crate.counter_snapshot()["error.NO_RESPONDER"] == 1


def test_access_running_off_the_end_of_a_board_is_bus_error(crate: Crate) -> None:
    with pytest.raises(BusError):
        crate.read(0x1000 + 0x100, space="A16", width=Width.D16)


_MAP = RegisterMap(
    "toy", 0x10, AddressSpace.A16,
    (
        Register("CSR", 0x0, Width.D16, Access.RW, also=(Width.D8,)),
        Register("DATA", 0x2, Width.D16, Access.RO, reset=0x1234),
        Register("CMD", 0x4, Width.D16, Access.WO),
        Register("BIG", 0x8, Width.D32, Access.RW),
    ),
)


class ToyBoard(RegisterBoard):
    REGMAP = _MAP


def test_unsupported_width_and_access_are_bus_errors() -> None:
    c = Crate()
    c.install(ToyBoard("toy"), base=0x100, space="A16")
    with pytest.raises(BusError) as ei:
        c.read(0x108, space="A16", width=Width.D16)  # D16 half of a D32-only register
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH
    with pytest.raises(BusError) as ei:
        c.read(0x103, space="A16", width=Width.D8)  # DATA has no D8 access
    assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH
    with pytest.raises(BusError) as ei:
        c.write(0x102, 1, space="A16", width=Width.D16)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        c.read(0x104, space="A16", width=Width.D16)
    assert ei.value.cause is BusErrorCause.ACCESS
    with pytest.raises(BusError) as ei:
        c.read(0x106, space="A16", width=Width.D16)  # a hole in the map
    assert ei.value.cause is BusErrorCause.NO_RESPONDER
    # D8 access to a D16 register that allows it: big-endian bytes
    c.write(0x100, 0xA55A, space="A16", width=Width.D16)
    assert c.read(0x100, space="A16", width=Width.D8) == 0xA5
    assert c.read(0x101, space="A16", width=Width.D8) == 0x5A
    c.write(0x101, 0x00, space="A16", width=Width.D8)
    assert c.read(0x100, space="A16", width=Width.D16) == 0xA500
    assert c.read(0x102, space="A16", width=Width.D16) == 0x1234


def test_overlapping_boards_rejected_naming_both() -> None:
    c = Crate()
    c.install(RamBoard("first", 0x100), base=0x1000, space="A16")
    with pytest.raises(VmeConfigError, match="second.*overlaps.*first"):
        c.install(RamBoard("second", 0x100), base=0x10F0, space="A16")
    c.install(RamBoard("third", 0x100), base=0x10F0, space="A24")  # other space: fine


def test_board_window_must_fit_its_space() -> None:
    with pytest.raises(VmeConfigError, match="does not fit A16"):
        Crate().install(RamBoard("big", 0x100), base=0xFFF0, space="A16")


def test_every_access_advances_simulated_time(crate: Crate) -> None:
    t = [crate.clock.now_ns]
    crate.read(0x1000, space="A16", width=Width.D16)
    t.append(crate.clock.now_ns)
    crate.read(0x200000, space="A24", width=Width.D32)
    t.append(crate.clock.now_ns)
    steps = [b - a for a, b in itertools.pairwise(t)]
    assert all(100 <= s <= 1000 for s in steps), steps
    assert steps[1] > steps[0]  # a D32 cycle takes longer than a D16
    crate.delay(15e-6)
    assert crate.clock.now_ns == t[-1] + 15_000
    assert crate.now() == pytest.approx(crate.clock.now_ns * 1e-9)


def test_counters_by_space_width_and_errors(crate: Crate) -> None:
    crate.write(0x200000, 1, space="A24", width=Width.D8)
    crate.read(0x200000, space="A24", width=Width.D8)
    crate.read(0x80000000, space="A32", width=Width.D32)
    with pytest.raises(BusError):
        crate.read(0x1001, space="A16", width=Width.D16)
    snap = crate.counter_snapshot()
    assert snap["write.A24.D8"] == 1 and snap["read.A24.D8"] == 1 and snap["read.A32.D32"] == 1


def test_block_transfer_uses_blt_and_is_faster(crate: Crate) -> None:
    values = [0x01020304 * i for i in range(8)]
    t0 = crate.clock.now_ns
    crate.write_block(0x200200, values, space="A24", width=Width.D32)
    t_block = crate.clock.now_ns - t0
    assert crate.read_block(0x200200, 8, space="A24", width=Width.D32) == values
    t0 = crate.clock.now_ns
    for i, v in enumerate(values):
        crate.write(0x200200 + 4 * i, v, space="A24", width=Width.D32)
    assert t_block < crate.clock.now_ns - t0
    assert am_for(AddressSpace.A24, block=True).code == 0x3F


def test_value_must_fit_width(crate: Crate) -> None:
    with pytest.raises(ValueError, match="does not fit D8"):
        crate.write(0x200000, 0x100, space="A24", width=Width.D8)


@settings(max_examples=200, deadline=None)
@given(
    ops=st.lists(
        st.tuples(
            st.sampled_from(list(Width)),
            st.integers(0, 0xFF),
            st.integers(0, 0xFFFFFFFF),
        ),
        min_size=1, max_size=40,
    )
)
def test_ram_read_after_write_matches_a_byte_model(ops) -> None:
    c = Crate()
    c.install(RamBoard("ram", 0x100), base=0x4000, space="A24")
    model = bytearray(0x100)
    for width, off, value in ops:
        off -= off % int(width)
        off = min(off, 0x100 - int(width))
        value &= width.max_value
        c.write(0x4000 + off, value, space="A24", width=width)
        model[off : off + int(width)] = value.to_bytes(int(width), "big")
        assert c.read(0x4000 + off, space="A24", width=width) == value
    for off in range(0, 0x100, 4):
        assert c.read(0x4000 + off, space="A24", width=Width.D32) == int.from_bytes(model[off:off + 4], "big")
