"""Rig units ([[rig.unit]]): parsing, the refusals, and the unit's own part of the rig file."""

from __future__ import annotations

import copy

import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError, ConfigTable
from servo.joint_groups import rig_units, unit_named, unit_rig, watchdog_unit
from servo.rig import load_rig, rig_from_table

UNITS = ("leg1", "leg2", "leg3", "leg4", "arm")


def melmalec():
    return load_rig(resolve_rig("melmalec-16"))


def with_units(units: list[dict]):
    spec = melmalec()
    data = copy.deepcopy(spec.table.data)
    data["rig"]["unit"] = units
    return rig_from_table(ConfigTable(data, "test.toml"), "test.toml")


def test_melmalec_has_five_units_each_with_its_own_boards_and_the_crawler_with_the_arm() -> None:
    spec = melmalec()
    units = rig_units(spec)
    assert [u.name for u in units] == list(UNITS)
    assert sum(len(u.joints) for u in units) == 16
    arm = unit_named(units, "arm", "x")
    assert "crawler" in arm.joints and arm.indices == (12, 13, 14, 15)
    for u, unit in enumerate(units):
        assert set(unit.boards) == {f"adc{u}", f"dac{u}", f"quad{u}", f"pio{u}"}
    assert watchdog_unit(spec, units) == "leg1"


def test_a_unit_rig_holds_only_the_units_joints_and_boards() -> None:
    spec = melmalec()
    units = rig_units(spec)
    leg2 = unit_rig(spec, units[1])
    assert [j.name for j in leg2.joints] == ["leg2_swing", "leg2_lift", "leg2_knee"]
    assert [j.index for j in leg2.joints] == [0, 1, 2]
    assert {b.get_str("name") for b in leg2.table.table("crate").tables("board")} == {"adc1", "dac1", "quad1", "pio1"}
    assert leg2.watchdog is None  # the line is on leg1's PIO
    leg1 = unit_rig(spec, units[0])
    assert leg1.watchdog is not None and leg1.watchdog.line.board == "pio0"
    assert [u.name for u in rig_units(leg1)] == ["leg1"]


def test_a_rig_without_units_has_none() -> None:
    assert rig_units(load_rig(resolve_rig("jpl-arm"))) == []


def test_a_board_shared_by_two_units_is_refused_naming_the_board() -> None:
    units = [{"name": "a", "joints": ["leg1_swing", "leg1_lift"]}, {"name": "b", "joints": ["leg1_knee"]}]
    rest = [{"name": f"u{i}", "joints": [j]} for i, j in enumerate(
        ["leg2_swing", "leg2_lift", "leg2_knee", "leg3_swing", "leg3_lift", "leg3_knee", "leg4_swing",
         "leg4_lift", "leg4_knee", "arm_base", "arm_shoulder", "arm_elbow", "crawler"])]
    with pytest.raises(ConfigError, match="board 'dac0' serves unit 'a' too"):
        rig_units(with_units(units + rest))


def test_a_joint_in_two_units_or_in_none_is_refused() -> None:
    base = [{"name": u, "joints": list(j)} for u, j in
            ((u.name, u.joints) for u in rig_units(melmalec()))]
    twice = copy.deepcopy(base)
    twice[1]["joints"].append("leg1_swing")
    with pytest.raises(ConfigError, match="'leg1_swing' is in unit 'leg1' too"):
        rig_units(with_units(twice))
    none = copy.deepcopy(base)
    none[4]["joints"].remove("crawler")
    with pytest.raises(ConfigError, match="crawler in none"):
        rig_units(with_units(none))
    unknown = copy.deepcopy(base)
    unknown[0]["joints"].append("tail")
    with pytest.raises(ConfigError, match="rig.unit"):
        rig_units(with_units(unknown))


def test_an_unknown_unit_name_lists_the_rigs_units() -> None:
    with pytest.raises(ConfigError, match="leg1, leg2, leg3, leg4, arm"):
        unit_named(rig_units(melmalec()), "tail", "melmalec-16.toml")
