"""`vmehil crate`: list, demo, read/write, shell and error reporting."""

from __future__ import annotations

import io
import json

from emulators.crate_file import load_crate
from emulators.presets import resolve_rig
from vmehil.cli import main
from vmehil.commands.crate import shell


def test_crate_demo_probes_every_board(capsys) -> None:
    assert main(["crate", "--json", "demo"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {p["board"] for p in out["probes"]} == {b["name"] for b in out["boards"]}
    assert all(p["ok"] for p in out["probes"])


def test_crate_read_unmapped_is_an_error_without_traceback(capsys) -> None:
    assert main(["crate", "read", "A24", "0xF00000"]) == 2
    err = capsys.readouterr().err
    assert "bus error" in err and "Traceback" not in err


def test_crate_shell_runs_commands_and_reports_errors() -> None:
    crate = load_crate(resolve_rig(None))
    out = io.StringIO()
    status = shell(crate, io.StringIO("write A24 0x200000 0xBEEF; read A24 0x200000\nread A24 0x200001\n"), out)
    lines = out.getvalue().splitlines()
    assert lines[:2] == ["ok", "0xBEEF"]
    assert lines[2].startswith("error: bus error") and status == 1


def test_crate_list_of_a_rig_shows_its_wiring(capsys) -> None:
    assert main(["crate", "--json", "list"]) == 0
    boards = {b["name"]: b for b in json.loads(capsys.readouterr().out)}
    assert boards["adc0"]["wired"] == 13  # 7 pots + 6 tachs of jpl-arm
    assert main(["crate", "list"]) == 0
    assert "wired" in capsys.readouterr().out


def test_a_vme_name_or_value_that_is_not_one_is_bad_input(capsys) -> None:
    # typed refusals (hal.vme.VmeValueError): exit 2 with their text, not "unexpected" (3)
    cases = {
        ("crate", "read", "A17", "0x200000"): "unknown address space 'A17'; expected one of A16, A24, A32",
        ("crate", "read", "A24", "0x200000", "--width", "12"): "unknown data width 12; expected 8, 16 or 32",
        ("crate", "write", "A24", "0x200000", "0x1FFFF", "--width", "8"): "value 131071 does not fit D8 (0..255)",
        ("crate", "--bus", "bogus", "list"): "bus 'bogus': expected 'emulated', 'vme_user' or 'vme_user:DIR'",
    }
    for argv, text in cases.items():
        assert main(list(argv)) == 2, argv
        assert capsys.readouterr().err.strip().splitlines()[-1] == f"vmehil crate: error: {text}"


def test_crate_list_json_gives_each_boards_vendor_model_and_document(capsys) -> None:
    assert main(["crate", "--json", "list"]) == 0
    boards = {b["name"]: b for b in json.loads(capsys.readouterr().out)}
    assert all({"vendor", "model", "document"} <= b.keys() for b in boards.values())
    # the reference boards' docs (docs/boards/*.md); the existing keys stay
    assert {k: boards["adc0"][k] for k in ("type", "id", "vendor", "model", "document")} == {
        "type": "adc", "id": "0xAD16", "vendor": "vmehil (reference design)", "model": "ADC16-REF",
        "document": "docs/boards/adc.md"}
    assert (boards["dac0"]["model"], boards["dac0"]["document"]) == ("DAC8-REF", "docs/boards/dac.md")
    assert (boards["quad0"]["model"], boards["quad0"]["document"]) == ("QUAD4-REF", "docs/boards/quadrature.md")
    assert boards["bit3.window"]["model"] == "BIT3-REF"  # the card's window is the card's
    assert main(["crate", "list"]) == 0
    text = capsys.readouterr().out
    assert "vendor" in text.splitlines()[0] and "ADC16-REF" in text and "docs/boards/pio.md" in text
