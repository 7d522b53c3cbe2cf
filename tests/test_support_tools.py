"""The test tools of #28 themselves: trace lines and the doc-table reader (tests/support)."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from hal.vme.errors import BusError
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width
from tests.support.board_spec import doc_registers, map_differences
from tests.support.bus_trace import Cycle, RecordingBus, parse_cycle

cycles = st.builds(
    lambda op, space, width, address, value, block: Cycle(op, space, address * width, width,
                                                          value % (1 << (8 * width)), block),
    st.sampled_from("RW"), st.sampled_from(["A16", "A24", "A32"]), st.sampled_from([1, 2, 4]),
    st.integers(0, 0x3FFF), st.integers(0, 2**32 - 1), st.booleans())


@given(cycles)
def test_a_trace_line_reads_back_as_the_cycle_it_names(c: Cycle) -> None:
    assert parse_cycle(str(c)) == c


def test_a_scripted_bus_answers_in_order_repeats_the_last_and_records_both_directions() -> None:
    bus = RecordingBus(answers={("A16", 0x4002): [0x0004, 0x0004, 0x0008]})
    assert [bus.read(0x4002) for _ in range(4)] == [4, 4, 8, 8]
    bus.write(0x4004, 0x0031)
    assert bus.trace()[-2:] == ["R A16 0x4002 D16 0x0008", "W A16 0x4004 D16 0x0031"]


def test_a_scripted_read_of_an_unnamed_address_is_a_bus_error() -> None:
    with pytest.raises(BusError):
        RecordingBus(answers={}).read(0x10)


DOC = """# A board
| offset | register | width | access | reset | bits | description |
|---|---|---|---|---|---|---|
| 0x00 | ID | D16 | RO | 0xAD16 |  | the ID |
| 0x02 | CSR | D16, D8 | RW | 0x0000 | [11:9] LEVEL — irq level<br>[1] SCAN — strobe<br>[0] START — strobe | control |
"""


def _map(start_lsb: int) -> RegisterMap:
    return RegisterMap("x", 0x10, AddressSpace.A16, (
        Register("ID", 0x00, Width.D16, Access.RO, reset=0xAD16),
        Register("CSR", 0x02, Width.D16, Access.RW, also=(Width.D8,),
                 fields=(Field("LEVEL", 9, 3), Field("SCAN", 1), Field("START", start_lsb))),
    ))


def test_the_doc_table_gives_offsets_widths_access_reset_and_fields(tmp_path) -> None:
    (tmp_path / "b.md").write_text(DOC)
    regs = doc_registers(tmp_path / "b.md")
    assert regs["CSR"].offset == 2 and regs["CSR"].also == ("D8",) and regs["ID"].reset == 0xAD16
    assert regs["CSR"].fields == {"LEVEL": (9, 3), "SCAN": (1, 1), "START": (0, 1)}


def test_a_map_that_agrees_has_no_differences_and_a_moved_bit_is_named(tmp_path) -> None:
    (tmp_path / "b.md").write_text(DOC)
    regs = doc_registers(tmp_path / "b.md")
    assert map_differences(_map(0), regs) == []
    diffs = map_differences(_map(2), regs)
    assert len(diffs) == 1 and "CSR fields" in diffs[0]
