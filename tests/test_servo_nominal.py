"""What the controller may know: the rig file's servo side (``[joint.servo.nominal]``), never
the plant's own parameters; and the plant reads only its own tables of the shared rig file."""

from __future__ import annotations

from pathlib import Path

import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError
from vmehil.system import build_emulated_rig


def _variant(tmp_path: Path, name: str, *subs: tuple[str, str], rig: str = "jpl-arm") -> Path:
    """The preset with each ``old`` replaced by ``new`` (first occurrence)."""
    text = resolve_rig(rig).read_text()
    for old, new in subs:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


def test_the_application_names_the_non_plant_tables_so_plant_typos_are_errors(tmp_path: Path) -> None:
    typo = _variant(tmp_path, "typo", ("\n[joint.friction]", "\n[joint.fricton]"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.fricton.*unknown key"):
        build_emulated_rig(typo)
    # [joint.calibration] (the pot procedure's travel) belongs to the calibration, not the plant
    travel = _variant(tmp_path, "travel", ("\n[joint.wiring]", "\n[joint.calibration]\n"
                                                              "pot_travel_deg = [-150.0, 150.0]\n[joint.wiring]"))
    build_emulated_rig(travel).close()
