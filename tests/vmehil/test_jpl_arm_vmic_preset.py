"""The preset ``jpl-arm-vmic``: the JPL arm of ``jpl-arm`` wired onto the VMIC boards and the SBS 617
(issue #31). Its plant and servo sections are ``jpl-arm``'s, copied (the rig format has no
include), so a test keeps them equal; its crate entries are the snippets the boards' own tests and
docs give; its wiring is ``jpl-arm``'s moved as the boards' docs say; `crate list` names every
board's vendor, model and document; the dry pass identifies each board as its doc says and
refuses the PCI card without a bus cycle."""

from __future__ import annotations

import copy
import json
import re
import tomllib
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from emulators.crate_file import load_crate
from emulators.presets import preset_names, resolve_rig
from hal.board_types import BOARD_TYPES
from servo.rig import load_rig
from servo.scene import default_scene_path, load_scene
from tests.support.boards import assert_boards_safe
from tests.support.vmivme3113a_preset import PRESET_BOARD as VMIVME_3113A_BOARD
from tests.vmehil.test_vmivme2536_rig import SNIPPET as VMIVME_2536_SNIPPET
from tests.vmehil.test_vservo_sbs617 import SBS617_BOARD
from vmehil.cli import main
from vmehil.rig_setup.real_bus import dry_pass
from vmehil.rig_setup.system import build_emulated_rig

PRESET = "jpl-arm-vmic"


def _load(name: str) -> dict[str, Any]:
    with open(resolve_rig(name), "rb") as f:
        return tomllib.load(f)


def _boards(data: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {b["name"]: b for b in data["crate"]["board"]}


@pytest.fixture(scope="module")
def vmic() -> dict[str, Any]:
    return _load(PRESET)


@pytest.fixture(scope="module")
def arm() -> dict[str, Any]:
    return _load("jpl-arm")


def test_the_preset_is_found_by_name_beside_jpl_arm() -> None:
    assert PRESET in preset_names()
    assert resolve_rig(PRESET).parent == resolve_rig("jpl-arm").parent
    assert load_rig(resolve_rig(PRESET)).name == PRESET  # its own calibration file: calibration/jpl-arm-vmic.toml


# ---- the copy of jpl-arm: plant and servo sections equal, so the two presets cannot drift ------

#: [rig] keys that say how the rig is wired, not how the arm behaves
WIRING_RIG_KEYS = {"name", "description", "references", "loopback", "readback"}


def test_the_plant_and_servo_sections_equal_jpl_arms(vmic, arm) -> None:
    for section in ("servo", "arm", "plant"):
        assert vmic[section] == arm[section], section
    behaviour = {k: v for k, v in vmic["rig"].items() if k not in WIRING_RIG_KEYS}
    assert {**behaviour, "watchdog": {**behaviour["watchdog"], "line": None}} == {
        **{k: v for k, v in arm["rig"].items() if k not in WIRING_RIG_KEYS},
        "watchdog": {**arm["rig"]["watchdog"], "line": None}}
    assert [j["name"] for j in vmic["joint"]] == [j["name"] for j in arm["joint"]]
    for jv, ja in zip(vmic["joint"], arm["joint"], strict=True):
        # every table of the joint — motor, gear, friction, link, amplifier, sensors, brake, servo
        # and its nominal values — but the wiring
        assert {k: v for k, v in jv.items() if k != "wiring"} == {k: v for k, v in ja.items() if k != "wiring"}, \
            jv["name"]
    # and the check can fail: a drifted friction figure is seen
    drifted = copy.deepcopy(vmic)
    drifted["joint"][0]["friction"]["breakout_nm"] = 0.05
    assert drifted["joint"][0] != {**arm["joint"][0], "wiring": drifted["joint"][0]["wiring"]}



def test_the_scene_is_jpl_arms() -> None:
    """Same arm, same setting: the preset's own scene file (used by default, as jpl-arm's is) holds
    the same obstacles as jpl-arm's, so a move refused on one is refused on the other."""
    vmic_scene = default_scene_path(resolve_rig(PRESET))
    arm_scene = default_scene_path(resolve_rig("jpl-arm"))
    assert vmic_scene.is_file()
    assert tomllib.loads(vmic_scene.read_text()) == tomllib.loads(arm_scene.read_text())
    assert len(load_scene(vmic_scene).obstacles) == 12  # the paper's twelve (docs/motion-safety.md)

# ---- the boards: the entries the boards' tests and docs give ---------------------------------

def test_the_crate_holds_the_documented_boards_under_their_names(vmic) -> None:
    assert {n: b["type"] for n, b in _boards(vmic).items()} == {
        "adc0": "vmivme-3113a", "dac0": "vmivme-4116", "dio0": "vmivme-2536", "vision-link": "sbs617",
        "pio0": "pio", "quad0": "quad", "quad1": "quad", "ram0": "ram"}


def test_the_commercial_boards_entries_are_the_snippets_of_their_tests(vmic, arm) -> None:
    boards = _boards(vmic)
    assert boards["adc0"] == tomllib.loads(VMIVME_3113A_BOARD)["crate"]["board"][0]
    snippet = tomllib.loads(VMIVME_2536_SNIPPET)
    assert boards["dio0"] == snippet["crate"]["board"][0]
    assert vmic["rig"]["watchdog"]["line"] == snippet["rig"]["watchdog"]["line"] == "dio0:OUT16"
    assert vmic["rig"]["readback"] == snippet["rig"]["readback"]
    # the 617 as its test has it, in the host's slot 1 (the CPU's: a PCI card has no VME slot)
    assert boards["vision-link"] == {**tomllib.loads(SBS617_BOARD)["crate"]["board"][0], "slot": 1}
    # the 4116: jpl-arm's dac0 (slot, base, the per-channel errors) with the settings its doc names
    assert boards["dac0"] == {**_boards(arm)["dac0"], "type": "vmivme-4116", "update": "synchronized",
                              "coding": "offset_binary"}
    # the reference boards the rig keeps, as in jpl-arm
    for name in ("pio0", "quad0", "quad1", "ram0"):
        assert boards[name] == _boards(arm)[name], name


def test_the_wiring_is_jpl_arms_moved_as_the_boards_docs_say(vmic, arm) -> None:
    # docs/boards/vmivme-3113a.md ("The arm's wiring"): current monitors on 16..22, references
    # 28/29, loopback 30/31; docs/boards/vmivme2536.md: the joints' digital lines on dio0
    imon = {"j1": "adc0:16", "j2": "adc0:17", "j3": "adc0:18", "j4": "adc0:19", "j5": "adc0:20",
            "j6": "adc0:21", "hand": "adc0:22"}
    digital = tomllib.loads(VMIVME_2536_SNIPPET)["wiring"]
    for jv, ja in zip(vmic["joint"], arm["joint"], strict=True):
        # jpl-arm's tactile switches sit on its pio1, which the VMIC rig has not (docs/hand.md): not wired there
        arm_wiring = {k: v for k, v in ja["wiring"].items() if not k.startswith("tactile_")}
        expected = {**arm_wiring, **digital.get(jv["name"], {}), "imon": imon[jv["name"]]}
        assert jv["wiring"] == expected, jv["name"]
    hand = vmic["joint"][-1]["wiring"]
    assert all(hand[k].startswith("pio0:") for k in ("pwm", "direction", "brake", "amp_enable", "amp_fault",
                                                     "amp_reset"))  # the H-bridge stays on the reference PIO
    assert vmic["rig"]["references"] == {"adc0:28": 5.0, "adc0:29": 0.0}
    assert vmic["rig"]["loopback"] == {"dac0:6": "adc0:30", "dac0:7": "adc0:31"}


def test_each_board_entry_is_labelled_commercial_or_reference_as_the_board_table_says() -> None:
    label = None
    seen: dict[str, str] = {}
    lines = resolve_rig(PRESET).read_text().splitlines()
    for k, line in enumerate(lines):
        if line.startswith("# COMMERCIAL") or line.startswith("# REFERENCE DESIGN"):
            label = line.split(":")[0][2:]
        elif line == "[[crate.board]]":
            m = re.match(r'type = "([^"]+)"', lines[k + 1])
            assert m and label is not None, lines[k + 1]
            seen[m[1]] = label
    assert seen == {t: "REFERENCE DESIGN" if BOARD_TYPES[t].vendor.startswith("vmehil") else "COMMERCIAL"
                    for t in seen}
    assert set(seen) == {"vmivme-3113a", "vmivme-4116", "vmivme-2536", "pio", "quad", "sbs617", "ram"}


def test_every_board_window_is_disjoint(tmp_path: Path) -> None:
    system = build_emulated_rig(resolve_rig(PRESET), seed=0, calibration=None)
    windows: dict[str, list[tuple[int, int, str]]] = {}
    for row in system.crate.describe():
        windows.setdefault(row["space"], []).append((int(row["base"], 16), int(row["end"], 16), row["name"]))
    for space, spans in windows.items():
        spans.sort()
        for (_, end, a), (base, _, b) in pairwise(spans):
            assert end < base, f"{space}: {a} overlaps {b}"
    assert {n for _, _, n in windows["A16"]} == {"adc0", "dac0", "dio0", "pio0", "quad0", "quad1"}
    system.close()


# ---- the rig built: drivers by role, a safe stop on the commercial boards ---------------------

def test_the_rig_builds_on_the_commercial_drivers_and_a_stop_leaves_them_safe() -> None:
    system = build_emulated_rig(resolve_rig(PRESET), seed=0, calibration=None)
    try:
        io = system.io
        assert {n: type(d).__name__ for n, d in io.adc.items()} == {"adc0": "Vmivme3113aDriver"}
        assert {n: type(d).__name__ for n, d in io.dac.items()} == {"dac0": "VmiVme4116Driver"}
        assert {n: type(d).__name__ for n, d in io.pio.items()} == {"dio0": "Vmi2536Driver", "pio0": "PioDriver"}
        io.enable(True)
        io.write_torque([0.1] * system.rig.n_joints)
        s = system.crate.signals
        assert all(s.get_digital(j.net("amp_enable")) for j in system.rig.joints)
        assert io.safe_stop() == []
        system.crate.delay(20e-6)  # the 4116's settling, twice
        assert not any(s.get_digital(j.net("amp_enable")) for j in system.rig.joints)
        assert system.crate.boards["dac0"].converter == [0x8000] * 8  # the 0 V code, offset binary
        assert_boards_safe(system)
    finally:
        system.close()


# ---- vmehil crate list --rig jpl-arm-vmic ----------------------------------------------------

def test_crate_list_names_each_boards_vendor_model_and_document(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["crate", "list", "--rig", PRESET, "--json"]) == 0
    rows = {r["name"]: (r["vendor"], r["model"], r["document"]) for r in json.loads(capsys.readouterr().out)}
    reference = "vmehil (reference design)"
    sbs = ("SBS Technologies (Bit 3)", "Model 617 PCI-to-VME adaptor", "docs/boards/sbs617.md")
    assert rows == {
        "adc0": ("VMIC", "VMIVME-3113A", "docs/boards/vmivme-3113a.md"),
        "dac0": ("VMIC", "VMIVME-4116", "docs/boards/vmivme4116.md"),
        "dio0": ("VMIC", "VMIVME-2536", "docs/boards/vmivme2536.md"),
        "vision-link": sbs, "vision-link.map": sbs, "vision-link.window": sbs,
        "pio0": (reference, "PIO24-REF", "docs/boards/pio.md"),
        "quad0": (reference, "QUAD4-REF", "docs/boards/quadrature.md"),
        "quad1": (reference, "QUAD4-REF", "docs/boards/quadrature.md"),
        "ram0": (reference, "RAM", "docs/vme.md"),
    }
    assert main(["crate", "list", "--rig", PRESET]) == 0
    text = capsys.readouterr().out
    for word in ("vendor", "model", "document", "VMIVME-3113A", "docs/boards/vmivme2536.md", "Model 617"):
        assert word in text


def test_the_617s_bars_show_in_the_hosts_slot_not_in_other_cards(capsys: pytest.CaptureFixture[str]) -> None:
    # the card's map and window took the crate's next free slot numbers, which were ram0's and dio0's
    assert main(["crate", "list", "--rig", PRESET, "--json"]) == 0
    slots = {r["name"]: r["slot"] for r in json.loads(capsys.readouterr().out)}
    assert slots["vision-link"] == slots["vision-link.map"] == slots["vision-link.window"] == 1
    assert (slots["ram0"], slots["dio0"]) == (9, 10)


# ---- the dry pass (--bus vme_user's first step), on the emulated crate ------------------------

def test_the_dry_pass_identifies_each_vme_board_as_its_doc_says_and_refuses_the_pci_card() -> None:
    spec = load_rig(resolve_rig(PRESET))
    system = build_emulated_rig(spec, seed=0, calibration=None)
    try:
        before = system.crate.counter_snapshot()
        checks = {c.name: c for c in dry_pass(system.crate, spec)}
        after = system.crate.counter_snapshot()
    finally:
        system.close()
    assert checks["adc0"].ok and checks["adc0"].detail.startswith("ID 0x1100")  # docs/boards/vmivme-3113a.md
    # docs/boards/vmivme4116.md, open point 8: no ID register, the CSR must answer
    assert checks["dac0"].ok and checks["dac0"].detail.startswith("no ID register (VMIVME-4116); CSR 0x")
    # docs/boards/vmivme2536.md, open point 1: the registers answer at the sources' widths; BID reported
    assert checks["dio0"].ok and checks["dio0"].detail.startswith("BID 0x")
    assert "not compared" in checks["dio0"].detail
    for name in ("pio0", "quad0", "quad1", "ram0"):
        assert checks[name].ok, checks[name].detail
    link = checks["vision-link"]
    assert not link.ok and link.detail.startswith("a PCI card in the host, not a VME board (Model 617")
    assert "vme_user cannot reach" in link.detail and "a rig file without it" in link.detail
    # never read: on a VME bus its BAR addresses would be another board's
    assert not any(k.startswith(("read.A32", "write.A32")) and after[k] != before.get(k, 0) for k in after)


def test_a_reference_adc_where_the_preset_names_the_3113a_is_refused_naming_both(tmp_path: Path) -> None:
    crate_file = tmp_path / "crate.toml"  # the slot holds vmehil's reference ADC at the 3113A's base
    crate_file.write_text('[crate]\nname = "wrong"\n\n[[crate.board]]\ntype = "adc"\nname = "adc0"\n'
                          'space = "A16"\nbase = 0x8500\n')
    check = next(c for c in dry_pass(load_crate(crate_file), load_rig(resolve_rig(PRESET))) if c.name == "adc0")
    assert not check.ok
    assert check.detail == (
        "ID reads 0xAD16, the rig's vmivme-3113a has 0x1100: the rig file names type vmivme-3113a (VMIVME-3113A by "
        "VMIC, docs/boards/vmivme-3113a.md, ID 0x1100); the slot holds type adc (ADC16-REF by vmehil (reference "
        "design), docs/boards/adc.md, ID 0xAD16)")
