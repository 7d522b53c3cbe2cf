"""The register-declaration type (hal.vme.registers): fields, registers and a map's refusal of a
bad declaration. Every board's map is built at import, before any test runs, so these checks
build small maps of their own, with values worked out by hand."""

from __future__ import annotations

import pytest

from hal.vme.registers import Access, Field, Register, RegisterMap, fields, registers
from hal.vme.types import AddressSpace, Width


def test_access_kinds_readable_and_writable() -> None:
    assert [(a.readable, a.writable) for a in (Access.RO, Access.WO, Access.RW, Access.W1C)] == [
        (True, False), (False, True), (True, True), (True, True)]
    assert Access.W1C.value == "RW1C"


def test_field_mask_get_and_put_at_bits_3_and_4() -> None:
    f = Field("mode", 3, 2)
    assert f.mask == 0x18
    assert f.get(0xFF) == 3
    assert f.get(0b1_0110) == 2  # bits 4..3 = 10
    assert f.put(0xFF, 1) == 0xEF  # bit 4 cleared, bit 3 kept, the rest untouched
    assert f.put(0x00, 3) == 0x18
    assert Field("bit", 7).mask == 0x80  # width defaults to one bit


def test_field_put_refuses_a_value_that_does_not_fit() -> None:
    f = Field("mode", 3, 2)
    assert f.put(0, 3) == 0x18  # the largest that fits
    with pytest.raises(ValueError, match=r"^4 does not fit the 2-bit field mode$"):
        f.put(0, 4)
    with pytest.raises(ValueError, match=r"^-1 does not fit the 2-bit field mode$"):
        f.put(0, -1)


def test_register_pack_unpack_and_field_lookup() -> None:
    csr = Register("CSR", 0x00, Width.D16, Access.RW,
                   fields=fields(Field("start", 0), Field("gain", 4, 2), Field("chan", 8, 4)))
    assert csr.field("gain") == Field("gain", 4, 2)
    assert csr.pack(start=1, gain=2, chan=0xA) == 0x0A21
    assert csr.pack() == 0
    assert csr.pack(gain=True) == 0x10  # a bool is taken as 0/1
    assert csr.unpack(0x0A21) == {"start": 1, "gain": 2, "chan": 0xA}
    with pytest.raises(KeyError, match=r"register CSR has no field 'scan'"):
        csr.field("scan")
    with pytest.raises(ValueError, match="does not fit the 2-bit field gain"):
        csr.pack(gain=4)
    plain = Register("DATA", 0x02, Width.D16, Access.RO)
    assert (plain.fields, plain.reset, plain.doc, plain.also) == ((), 0, "", ())


def _map(*regs: Register, size: int = 0x10) -> RegisterMap:
    return RegisterMap("toy", size, AddressSpace.A16, registers(regs))


def test_map_looks_registers_up_by_name_start_and_byte() -> None:
    a = Register("A", 0x00, Width.D16, Access.RW)
    b = Register("B", 0x02, Width.D8, Access.RO)
    c = Register("C", 0x04, Width.D32, Access.WO)
    m = _map(a, b, c, size=0x08)
    assert (m["A"], m["B"], m["C"]) == (a, b, c)
    assert [m.at(o) for o in range(8)] == [a, None, b, None, c, None, None, None]
    assert [m.containing(o) for o in range(9)] == [a, a, b, None, c, c, c, c, None]
    with pytest.raises(KeyError, match=r"toy has no register 'D'"):
        m["D"]


def test_map_refuses_a_duplicate_name() -> None:
    with pytest.raises(ValueError, match=r"^toy: duplicate register name A$"):
        _map(Register("A", 0x00, Width.D16, Access.RW), Register("A", 0x02, Width.D16, Access.RW))


def test_map_refuses_an_offset_not_aligned_to_the_width() -> None:
    _map(Register("W", 0x04, Width.D32, Access.RW))  # aligned: accepted
    _map(Register("B", 0x03, Width.D8, Access.RW))  # a byte anywhere
    with pytest.raises(ValueError, match=r"^toy\.H: offset 0x3 not aligned$"):
        _map(Register("H", 0x03, Width.D16, Access.RW))
    with pytest.raises(ValueError, match=r"^toy\.W: offset 0xA not aligned$"):
        _map(Register("W", 0x0A, Width.D32, Access.RW))


def test_map_refuses_a_register_beyond_the_window() -> None:
    _map(Register("LAST", 0x0E, Width.D16, Access.RW), size=0x10)  # ends exactly at the top
    _map(Register("TOP", 0x0F, Width.D8, Access.RW), size=0x10)
    with pytest.raises(ValueError, match=r"^toy\.OUT: beyond the board window$"):
        _map(Register("OUT", 0x10, Width.D8, Access.RW), size=0x10)
    with pytest.raises(ValueError, match=r"^toy\.OUT: beyond the board window$"):
        _map(Register("OUT", 0x0C, Width.D32, Access.RW), size=0x0E)


def test_map_refuses_overlapping_registers_and_accepts_neighbours() -> None:
    m = _map(Register("A", 0x00, Width.D16, Access.RW), Register("B", 0x02, Width.D16, Access.RW),
             Register("C", 0x04, Width.D8, Access.RW), Register("D", 0x05, Width.D8, Access.RW))
    assert m.containing(0x05).name == "D"
    m = _map(Register("HI", 0x02, Width.D16, Access.RW), Register("LO", 0x00, Width.D16, Access.RW))  # any order
    assert (m.at(0).name, m.at(2).name) == ("LO", "HI")
    with pytest.raises(ValueError, match=r"^toy: registers A and B overlap$"):
        _map(Register("A", 0x00, Width.D32, Access.RW), Register("B", 0x02, Width.D16, Access.RW))
    with pytest.raises(ValueError, match=r"^toy: registers A and B overlap$"):
        _map(Register("A", 0x04, Width.D16, Access.RW), Register("B", 0x04, Width.D8, Access.RW))
    with pytest.raises(ValueError, match=r"^toy: registers A and B overlap$"):
        _map(Register("A", 0x02, Width.D16, Access.RW), Register("B", 0x03, Width.D8, Access.RW))
    with pytest.raises(ValueError, match=r"^toy: registers A and B overlap$"):  # B below A, reaching into it
        _map(Register("A", 0x05, Width.D8, Access.RW), Register("B", 0x04, Width.D32, Access.RW))
    with pytest.raises(ValueError, match=r"^toy: registers B and C overlap$"):  # checked against every earlier one
        _map(Register("A", 0x00, Width.D8, Access.RW), Register("B", 0x04, Width.D16, Access.RW),
             Register("C", 0x05, Width.D8, Access.RW))
