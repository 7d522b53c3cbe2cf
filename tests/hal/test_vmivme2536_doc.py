"""The VMIVME-2536's doc (docs/boards/vmivme2536.md) is its spec: the driver's register map and the
emulator's own declaration are each checked against the doc's register table, never against each
other; the facts the doc cites from the Duke FEL EPICS support are checked as literals."""

from __future__ import annotations

import pytest

from emulators.vmivme2536 import VMI2536_BOARD_MAP
from hal.pio import VMI2536_REGS
from tests.support.board_spec import DOCS, doc_registers, map_differences


@pytest.fixture(scope="module")
def doc():
    return doc_registers("vmivme2536")


def test_the_doc_states_the_four_registers_of_the_epics_struct(doc) -> None:
    # drvVmi2536.h: bid (short), csr (short), input (long), output (long) — then a reserved long
    assert {n: (r.offset, r.width, r.access) for n, r in doc.items()} == {
        "BID": (0x00, "D16", "RO"), "CSR": (0x02, "D16", "RW"),
        "INPUT": (0x04, "D32", "RO"), "OUTPUT": (0x08, "D32", "RW"),
    }
    # LED_OFF 0x8000, OUTPUTS_ON 0x4000, INPUTS_ON 0x2000 (drvVmi2536.h:13-15)
    assert doc["CSR"].fields == {"led_off": (15, 1), "outputs_on": (14, 1), "inputs_on": (13, 1)}
    assert doc["BID"].reset is None  # not published: the doc states no value
    assert (doc["CSR"].reset, doc["OUTPUT"].reset, doc["INPUT"].reset) == (0x0000, 0x0, 0x0)


def test_the_drivers_register_map_is_the_docs_table(doc) -> None:
    assert map_differences(VMI2536_REGS, doc, who="driver") == []
    assert VMI2536_REGS.size == 0x10 and VMI2536_REGS.space.name == "A16"


def test_the_emulators_own_register_map_is_the_docs_table(doc) -> None:
    assert map_differences(VMI2536_BOARD_MAP, doc, who="emulator") == []
    assert VMI2536_BOARD_MAP.size == 0x10 and VMI2536_BOARD_MAP.space.name == "A16"


def test_the_doc_cites_its_source_by_repository_path_and_commit() -> None:
    text = (DOCS / "vmivme2536.md").read_text()
    for needle in ("hartmansm/DFELL_EPICS", "vmi2536/drvVmi2536.h", "vmi2536/drvVmi2536.c",
                   "vmi2536/devBxVmi2536.c", "9f0d117429f654bf7b9cbc6c3f5c2234d3fce1bf"):
        assert needle in text


def test_the_doc_says_what_the_outputs_are_after_reset_and_how_the_hand_is_driven() -> None:
    text = (DOCS / "vmivme2536.md").read_text()
    assert "**off after reset**" in text and "every enable low" in text
    assert "keep the reference PIO board for the\n   hand" in text
