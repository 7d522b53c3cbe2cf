"""docs/boards/vmivme-3113a.md is the spec: the driver's register map and conversions, and the
emulator's own map and quantizer, are each checked against the doc's tables (never against each
other). Worked examples: the doc's "Conversion" table, computed there by hand."""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.vmivme3113a import Vmivme3113aBoard
from hal.adc_dac.vmivme3113a_format import (
    Vmi3113aFormat,
    Vmi3113aRange,
    code_from_word,
    lsb_v,
    volts_from_code,
)
from hal.adc_dac.vmivme3113a_regs import VMI3113A_REGMAP
from hal.vme import Width
from tests.support.board_spec import doc_registers, doc_rows, map_differences

DOC = "vmivme-3113a"
BASE = 0x8500
#: the doc's range names (first column of the examples) → the jumper setting
_RANGE = {"±10 V": "bipolar_10v", "±5 V": "bipolar_5v", "0..10 V": "unipolar_10v"}


def _num(text: str) -> float:
    return float(text.replace("−", "-").replace("+", ""))


def _examples() -> list[tuple[str, float, int, int, float]]:
    rows = doc_rows(DOC, "range", "input V", "offset binary", "two's complement", "code centre V")
    return [(_RANGE[r["range"]], _num(r["input v"]), int(r["offset binary"], 16), int(r["two's complement"], 16),
             _num(r["code centre v"])) for r in rows]


def test_the_driver_register_map_is_the_docs_register_table() -> None:
    assert map_differences(VMI3113A_REGMAP, doc_registers(DOC), who="driver") == []


def test_the_emulator_register_map_is_the_docs_register_table() -> None:
    assert map_differences(Vmivme3113aBoard.REGMAP, doc_registers(DOC), who="emulator") == []


def test_the_doc_states_64_channel_words_from_0x80() -> None:
    regs = doc_registers(DOC)
    assert [regs[f"CH{k}"].offset for k in range(64)] == [0x80 + 2 * k for k in range(64)]
    assert regs["ID"].reset == 0x1100


def test_the_driver_decodes_the_docs_worked_examples() -> None:
    examples = _examples()
    assert len(examples) == 17  # every range, both formats
    for rng, _, ob, tc, centre in examples:
        assert code_from_word(ob, Vmi3113aFormat.OFFSET_BINARY) == ob, (rng, hex(ob))
        assert code_from_word(tc, Vmi3113aFormat.TWOS_COMPLEMENT) == ob, (rng, hex(tc))
        assert volts_from_code(ob, Vmi3113aRange.parse(rng)) == centre, (rng, hex(ob))


@pytest.mark.parametrize(("rng", "lsb"), [
    ("bipolar_10v", 0.0048828125), ("bipolar_5v", 0.00244140625), ("unipolar_10v", 0.00244140625)])
def test_the_driver_lsb_of_each_range_is_the_docs(rng: str, lsb: float) -> None:
    assert lsb_v(Vmi3113aRange.parse(rng)) == lsb


def test_the_emulator_converts_the_docs_worked_examples_in_both_formats() -> None:
    """The emulator driven through the doc's own bit positions (CSR.TWOS_COMPLEMENT, CSR.MODE,
    the CH words' offsets): each example's input gives the doc's word in each format."""
    regs = doc_registers(DOC)
    csr, ch7 = regs["CSR"], regs["CH7"]
    twos = 1 << csr.fields["TWOS_COMPLEMENT"][0]
    for rng, volts, ob, tc, _ in _examples():
        c = Crate("doc")
        c.install(Vmivme3113aBoard("adc0", wiring={7: "in7"}, input_range=rng), base=BASE, space="A16")
        c.signals.set_analog("in7", volts)
        c.delay(80e-6)  # channel 7 ends its first conversion at 80 µs
        assert c.read(BASE + ch7.offset, space="A16", width=Width.D16) == ob, (rng, volts)
        c.write(BASE + csr.offset, twos, space="A16", width=Width.D16)
        c.delay(640e-6)  # its next conversion, stored in two's complement
        assert c.read(BASE + ch7.offset, space="A16", width=Width.D16) == tc, (rng, volts)
