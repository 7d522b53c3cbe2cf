"""The board-type tables: the driver side's (``hal.board_types``) and the emulators'
(``emulators.board_types``) name the same types; each entry's driver, probe and metadata load as
the board docs say."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from emulators.board_types import BUILTIN_BOARD_TYPES as EMULATOR_TYPES
from hal.adc_dac.adc import AdcDriver
from hal.adc_dac.dac import DacDriver
from hal.bit3.driver import Bit3Driver
from hal.board_types import BOARD_TYPES, BUILTIN_BOARD_TYPES, BoardType, RegisterProbe, board_role
from hal.pio.pio import PioDriver
from hal.quadrature.quad import QuadratureDriver

REPO = Path(__file__).resolve().parents[1]


def test_the_driver_and_the_emulator_tables_name_the_same_board_types() -> None:
    expected = {"adc", "dac", "pio", "quad", "bit3", "ram", "vmivme-4116", "vmivme-2536", "sbs617", "vmivme-3113a"}
    assert set(BUILTIN_BOARD_TYPES) == expected
    assert set(EMULATOR_TYPES) == expected


def test_ram_is_in_the_driver_table_without_a_driver_or_an_id_register() -> None:
    # RAM is memory: no driver package drives it and it has no ID register; it is in the driver
    # table for its role and metadata only (what `crate list` shows of a RAM slot).
    ram = BOARD_TYPES["ram"]
    assert (ram.role, ram.driver, ram.probe) == ("ram", None, None)
    assert ram.load_probe() is None and ram.channels() is None
    with pytest.raises(LookupError, match="no driver"):
        ram.load_driver()


def test_each_board_type_loads_the_driver_its_doc_names() -> None:
    # docs/boards/*.md name the driver classes
    drivers = {"adc": AdcDriver, "dac": DacDriver, "pio": PioDriver, "quad": QuadratureDriver, "bit3": Bit3Driver}
    for name, cls in drivers.items():
        assert BOARD_TYPES[name].load_driver() is cls, name
        assert board_role(name) == name


def test_each_probe_expects_the_id_its_doc_gives() -> None:
    # the ID registers of docs/boards/{adc,dac,pio,quadrature,bit3}.md: (offset, value)
    ids = {"adc": (0x00, 0xAD16), "dac": (0x00, 0xDA08), "pio": (0x00, 0x5001), "quad": (0x00, 0x5101),
           "bit3": (0x0E, 0x0413)}
    for name, (offset, value) in ids.items():
        probe = BOARD_TYPES[name].load_probe()
        assert isinstance(probe, RegisterProbe), name
        reg = BOARD_TYPES[name].id_register()
        assert reg is not None and (reg.offset, reg.reset) == (offset, value), name


def test_channel_counts_come_from_the_drivers() -> None:
    # docs/boards: 16 ADC channels, 8 DAC channels, 4 quadrature channels
    assert {n: BOARD_TYPES[n].channels() for n in ("adc", "dac", "quad")} == {"adc": 16, "dac": 8, "quad": 4}


def test_every_entry_names_a_document_that_exists_and_its_vendor_and_model() -> None:
    for name, bt in BUILTIN_BOARD_TYPES.items():
        assert (REPO / bt.document).is_file(), (name, bt.document)
        reference = name in ("adc", "dac", "pio", "quad", "bit3", "ram")  # the rest are commercial boards (#31)
        assert (bt.vendor == "vmehil (reference design)") == reference and bt.vendor and bt.model, name
    assert BOARD_TYPES["adc"].metadata() == {"vendor": "vmehil (reference design)", "model": "ADC16-REF",
                                             "document": "docs/boards/adc.md"}


def test_a_role_that_is_not_one_is_refused() -> None:
    with pytest.raises(ValueError, match="board role 'scope' is not one of adc, dac, pio, quad, bit3, ram"):
        BoardType("scope", "Acme", "X", "x.md")


def test_the_table_imports_no_driver_package_until_an_entry_is_used() -> None:
    # the strings are resolved on first use: so emulators (which must not import a driver package)
    # may read the table, and reading it costs no driver import
    code = ("import sys, hal.board_types as t; t.BOARD_TYPES['adc'].metadata(); "
            "print(sorted(m for m in sys.modules if m.startswith(('hal.adc_dac', 'hal.pio', 'hal.quadrature', "
            "'hal.amplifiers', 'hal.bit3'))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    assert out.stdout.strip() == "[]"


def test_the_board_index_lists_every_board_type_as_the_table_has_it() -> None:
    # docs/boards/README.md: type | vendor | model | document | role | reference or commercial | dry pass | arm
    rows = {}
    for line in (REPO / "docs" / "boards" / "README.md").read_text().splitlines():
        if line.startswith("| `"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            rows[cells[0].strip("`")] = cells
    assert set(rows) == set(BOARD_TYPES.names())
    for name, (_, vendor, model, document, role, kind, dry_pass, _arm) in rows.items():
        bt = BOARD_TYPES[name]
        link = document.split("](")[1].rstrip(")")
        assert (vendor, model, role) == (bt.vendor, bt.model, bt.role), name
        assert (REPO / "docs" / "boards" / link).resolve() == (REPO / bt.document).resolve(), name
        assert kind == ("reference" if bt.vendor == "vmehil (reference design)" else "commercial"), name
        reg = bt.id_register()
        assert (reg is not None) == dry_pass.startswith("ID 0x"), name
        if reg is not None:
            assert dry_pass == f"ID 0x{reg.reset:X}", name
        assert ("PCI card" in dry_pass) == (bt.bus == "pci"), name
