"""docs/boards/sbs617.md is the spec: the driver's and the emulator's declarations are each checked
against its register tables (never against each other), and the doc's worked values are literals."""

from __future__ import annotations

from emulators.sbs617 import MAP_ENTRY_MAP, NODE_MAP
from hal.bit3 import SBS617_MAP_ENTRY, SBS617_NODE
from tests.support.board_spec import DOCS, doc_registers, map_differences

DOC = DOCS / "sbs617.md"


def test_driver_node_map_matches_the_doc() -> None:
    assert map_differences(SBS617_NODE, doc_registers(DOC, table=0), who="driver") == []


def test_emulator_node_map_matches_the_doc() -> None:
    assert map_differences(NODE_MAP, doc_registers(DOC, table=0), who="emulator") == []


def test_driver_map_entry_matches_the_doc() -> None:
    assert map_differences(SBS617_MAP_ENTRY, doc_registers(DOC, table=1), who="driver") == []


def test_emulator_map_entry_matches_the_doc() -> None:
    assert map_differences(MAP_ENTRY_MAP, doc_registers(DOC, table=1), who="emulator") == []


def test_every_node_register_is_one_byte_in_a_32_byte_block() -> None:
    regs = doc_registers(DOC, table=0)
    assert {r.width for r in regs.values()} == {"D8"}
    assert max(r.offset for r in regs.values()) == 0x1F
    assert SBS617_NODE.size == 0x20 and NODE_MAP.size == 0x20


def test_worked_map_entries_from_the_doc() -> None:
    # 0x400000 | 0x39 << 6 | 2 << 4, by hand: 0x400000 + 0xE40 + 0x20
    entry = SBS617_MAP_ENTRY["PCI_VME_MAP"]
    assert entry.pack(VME_PAGE=0x400, AM=0x39, FUNCTION=2) == 0x00400E60
    assert entry.pack(VME_PAGE=0x401, AM=0x39, FUNCTION=2) == 0x00401E60
    assert entry.pack(VME_PAGE=0x08000, AM=0x09, FUNCTION=2) == 0x08000260
    assert entry.pack(INVALID=1) == 0x00000001
    text = DOC.read_text()
    for literal in ("0x00400E60", "0x00401E60", "0x08000260", "0x00000001"):
        assert literal in text


def test_the_error_masks_are_the_netbsd_ones() -> None:
    from hal.bit3.sbs617_regs import LSR_LATCHED, LSR_NOT_USABLE

    assert (LSR_LATCHED, LSR_NOT_USABLE) == (0xC6, 0xC7)
