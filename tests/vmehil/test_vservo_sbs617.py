"""Visual servoing through the whole stack on the SBS (Bit 3) Model 617: the jpl-arm rig with its
vision link replaced by the crate-file snippet the jpl-arm-vmic preset uses for the card."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from emulators.presets import resolve_rig
from vmehil.cli import main

SBS617_BOARD = """[[crate.board]]
type = "sbs617"
name = "vision-link"
space = "A32"
base = 0x80000000
map_base = 0x80010000
window_base = 0x82000000
remote_space = "A24"
remote_base = 0x400000
mem_size = 0x1000
irq_level = 3
irq_vector = 0xB3

"""


def _rig_with_the_617(tmp_path: Path) -> Path:
    text = resolve_rig("jpl-arm").read_text()
    start = text.index('[[crate.board]]\ntype = "bit3"')
    end = text.index("[[crate.board]]", start + 1)
    rig = tmp_path / "jpl-arm-617.toml"
    rig.write_text(text[:start] + SBS617_BOARD + text[end:])
    return rig


@pytest.mark.slow
def test_inprocess_visual_servo_over_the_617_reaches_the_target(tmp_path: Path) -> None:
    out = tmp_path / "vs.json"
    assert main(["run", "--rig", str(_rig_with_the_617(tmp_path)), "--vision", "inprocess", "--quiet",
                 "--json", str(out)]) == 0
    v = json.loads(out.read_text())["vision"]
    assert v["end_reason"] == "PEER_ENDED" and v["robot_state"] == "IDLE" and v["commands"] > 10
    assert v["final_distance_mm"] < 8.0  # as on the reference card (tests/vmehil/test_vservo.py)


@pytest.mark.slow
def test_link_down_on_the_617_ends_the_task_with_link_error(tmp_path: Path) -> None:
    out = tmp_path / "vs.json"
    assert main(["run", "--rig", str(_rig_with_the_617(tmp_path)), "--vision", "inprocess", "--quiet",
                 "--duration", "6", "--fault", "bit3_link_down@4", "--json", str(out)]) == 0
    report = json.loads(out.read_text())
    assert [(f["target"], f["emulator_fault"]) for f in report["injected_faults"]] == [("vision-link", "link_down")]
    v = report["vision"]
    assert (v["robot_state"], v["end_reason"], v["commands"]) == ("IDLE", "LINK_ERROR", 0)


def test_crate_list_names_the_617_and_its_bars(tmp_path: Path, capsys) -> None:
    assert main(["crate", "list", "--rig", str(_rig_with_the_617(tmp_path)), "--json"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    for name, base in (("vision-link", 0x80000000), ("vision-link.map", 0x80010000),
                       ("vision-link.window", 0x82000000)):
        row = rows[name]
        assert (row["vendor"], row["model"], row["document"]) == (
            "SBS Technologies (Bit 3)", "Model 617 PCI-to-VME adaptor", "docs/boards/sbs617.md"), name
        assert row["space"] == "A32" and int(str(row["base"]), 0) == base, name
