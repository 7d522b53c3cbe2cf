"""The real-bus dry pass (``vmehil.rig_setup.real_bus.dry_pass``) identifies each board by its
type's probe and refuses a wrong board in a slot, naming both. The bus here is the emulated crate
itself (a ``VmeBus``); through the FUSE stand-in for /dev/bus/vme, see
tests/vmehil/commands/test_vme_user_commands.py."""

from __future__ import annotations

from pathlib import Path

import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from vmehil.rig_setup.real_bus import RealBusRefused, dry_pass, prepare_real_rig
from vmehil.rig_setup.system import build_emulated_rig


def swapped_adc0_dac0(tmp_path: Path) -> Path:
    """jpl-arm's rig file with adc0 and dac0 at each other's base (0x6000 ↔ 0x7000)."""
    text = resolve_rig("jpl-arm").read_text()
    assert text.count("base = 0x6000\n") == 1 and text.count("base = 0x7000\n") == 1
    text = text.replace("base = 0x6000\n", "base = @ADC@\n").replace("base = 0x7000\n", "base = 0x6000\n")
    path = tmp_path / "jpl-arm.toml"
    path.write_text(text.replace("base = @ADC@\n", "base = 0x7000\n"))
    return path


def test_the_dry_pass_identifies_every_board_of_the_right_crate() -> None:
    system = build_emulated_rig(None, seed=1)
    checks = {c.name: c for c in dry_pass(system.crate, system.rig)}
    assert all(c.ok for c in checks.values()), [c.detail for c in checks.values() if not c.ok]
    assert checks["adc0"].detail.startswith("ID 0xAD16")  # docs/boards/adc.md
    assert checks["quad0"].detail.startswith("ID 0x5101")  # docs/boards/quadrature.md
    assert checks["adc0"].as_dict()["model"] == "ADC16-REF"


def test_a_wrong_board_in_a_slot_is_refused_naming_both(tmp_path) -> None:
    system = build_emulated_rig(None, seed=1)  # the crate as built: adc0 at 0x6000, dac0 at 0x7000
    rig = load_rig(swapped_adc0_dac0(tmp_path))  # the rig file says the other way round
    checks = {c.name: c for c in dry_pass(system.crate, rig)}
    assert not checks["adc0"].ok and not checks["dac0"].ok
    assert checks["adc0"].detail == (
        "ID reads 0xDA08, the rig's adc has 0xAD16: the rig file names type adc (ADC16-REF by vmehil "
        "(reference design), docs/boards/adc.md, ID 0xAD16); the slot holds type dac (DAC8-REF by vmehil "
        "(reference design), docs/boards/dac.md, ID 0xDA08)")
    assert "the slot holds type adc (ADC16-REF" in checks["dac0"].detail
    with pytest.raises(RealBusRefused, match=r"dry pass failed, nothing enabled: adc0 \(adc A16 0x7000\): "
                                             r"ID reads 0xDA08.*the slot holds type dac"):
        prepare_real_rig(rig, system.crate)


def test_an_id_no_board_type_answers_is_named_as_unknown(tmp_path) -> None:
    system = build_emulated_rig(None, seed=1)
    system.crate.write(0x200000, 0x1234, space="A24", width=16)  # ram0: its first word
    text = resolve_rig("jpl-arm").read_text().replace('type = "ram"', 'type = "quad"')
    path = tmp_path / "jpl-arm.toml"
    path.write_text(text)
    checks = {c.name: c for c in dry_pass(system.crate, load_rig(path))}
    assert checks["ram0"].detail.endswith("the slot holds a board of no known type (ID 0x1234)")
