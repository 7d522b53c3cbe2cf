"""Plug-in points: a distribution installed beside ours adds a board type, a control object or a
calibration procedure through entry points, without editing our code; unknown names list the known."""

from __future__ import annotations

import json

import numpy as np
import pytest

import hal.plugins
from emulators.board_types import BOARD_TYPES
from emulators.crate_file import build_crate
from hal.config import ConfigError, ConfigTable
from hal.plugins import PluginError, PluginShadowWarning, PluginTable, UnknownPluginError
from servo.control import build_controller, unit_chain
from servo.control.objects import CONTROL_OBJECTS
from vmehil.calibration.procedure_runner import resolve_procedure_names
from vmehil.calibration.procedures import BUILTIN_PROCEDURES, PROCEDURES
from vmehil.cli import main

GROUP = "vmehil.test_things"

THINGS = """
    def shout(text):
        return text.upper()

    NOT_CALLABLE = 42
"""


def _things_table() -> PluginTable:
    def callable_only(name, obj):
        if not callable(obj):
            raise TypeError(f"not callable: {obj!r}")
        return obj

    return PluginTable(GROUP, "thing", {"echo": lambda text: text}, callable_only)


# ---- the shared mechanism (hal.plugins) ----------------------------------------------------------------
def test_an_installed_distribution_adds_a_name_beside_the_builtin_ones(install_distribution):
    install_distribution("acme-things", {"acme_things": THINGS}, {GROUP: {"shout": "acme_things:shout"}})
    things = _things_table()
    assert things["shout"]("hi") == "HI"
    assert things["echo"]("hi") == "hi"
    assert things.names() == ["echo", "shout"]
    assert "shout" in things and "whisper" not in things


def test_an_unknown_name_lists_the_builtin_and_the_installed_names(install_distribution):
    install_distribution("acme-things", {"acme_things": THINGS}, {GROUP: {"shout": "acme_things:shout"}})
    with pytest.raises(UnknownPluginError, match=r"unknown thing 'whisper'; known: echo, shout$") as ei:
        _things_table()["whisper"]
    assert isinstance(ei.value, KeyError) and ei.value.known == ["echo", "shout"]
    assert _things_table().get("whisper") is None


def test_a_builtin_lookup_does_not_read_the_installed_metadata(monkeypatch):
    def no_metadata(**kw):
        raise AssertionError("entry points read for a built-in name")

    monkeypatch.setattr(hal.plugins, "entry_points", no_metadata)
    assert _things_table()["echo"]("x") == "x"


def test_an_entry_point_cannot_replace_a_builtin(install_distribution):
    install_distribution("acme-things", {"acme_things": THINGS}, {GROUP: {"echo": "acme_things:shout"}})
    things = _things_table()
    with pytest.warns(PluginShadowWarning, match="'echo'.*acme-things.*built in"):
        assert things.names() == ["echo"]
    assert things["echo"]("hi") == "hi"


def test_a_broken_entry_point_is_an_error_naming_it_and_its_distribution(install_distribution):
    install_distribution("acme-things", {"acme_things": THINGS}, {GROUP: {
        "gone": "acme_things:missing", "number": "acme_things:NOT_CALLABLE", "noimport": "acme_nowhere:x"}})
    things = _things_table()
    with pytest.raises(PluginError, match=r"thing 'gone' \(entry point 'acme_things:missing' of acme-things"):
        things["gone"]
    with pytest.raises(PluginError, match="not callable: 42"):
        things["number"]
    with pytest.raises(PluginError, match="ModuleNotFoundError"):
        things["noimport"]
    assert things["echo"]("ok") == "ok"  # the others still work


def test_a_name_two_distributions_declare_is_refused_when_used(install_distribution):
    install_distribution("acme-things", {"acme_things": THINGS}, {GROUP: {"shout": "acme_things:shout"}})
    install_distribution("other-things", {"other_things": THINGS}, {GROUP: {"shout": "other_things:shout"}})
    with pytest.raises(PluginError, match="several installed distributions"):
        _things_table()["shout"]


# ---- board types (emulators) ---------------------------------------------------------------------------
SCRATCH_BOARDS = """
    from emulators.ram import RamBoard

    def scratch(name, cfg, ctx):
        return RamBoard(name, cfg.get_int("kib", 1) * 1024)
"""


def _crate_table(board_type: str) -> ConfigTable:
    return ConfigTable({"crate": {"board": [
        {"type": board_type, "name": "s0", "space": "A24", "base": 0x300000, "kib": 2}]}}, "crate.toml")


def test_a_board_type_from_an_installed_package_builds_in_a_crate_file(install_distribution, capsys):
    install_distribution("acme-boards", {"acme_boards": SCRATCH_BOARDS},
                         {"vmehil.board_types": {"scratch": "acme_boards:scratch"}})
    crate = build_crate(_crate_table("scratch"))
    assert crate.boards["s0"].size == 2048
    assert main(["crate", "types"]) == 0
    assert "scratch" in capsys.readouterr().out.split()


def test_an_unknown_board_type_lists_the_known_ones(install_distribution):
    install_distribution("acme-boards", {"acme_boards": SCRATCH_BOARDS},
                         {"vmehil.board_types": {"scratch": "acme_boards:scratch"}})
    with pytest.raises(ConfigError) as ei:
        build_crate(_crate_table("scrach"))
    assert ei.value.key == "crate.board[0].type"
    assert "adc, bit3, dac, pio, quad, ram, sbs617, scratch, vmivme-2536, vmivme-3113a, vmivme-4116" in str(ei.value)
    assert BOARD_TYPES.names() == ["adc", "bit3", "dac", "pio", "quad", "ram", "sbs617", "scratch", "vmivme-2536",
                                   "vmivme-3113a", "vmivme-4116"]


def test_a_broken_board_type_is_a_one_line_command_line_error(install_distribution, tmp_path, capsys):
    install_distribution("acme-boards", {"acme_boards": SCRATCH_BOARDS},
                         {"vmehil.board_types": {"scratch": "acme_boards:no_such_factory"}})
    crate_file = tmp_path / "crate.toml"
    crate_file.write_text('[crate]\n[[crate.board]]\ntype = "scratch"\nname = "s0"\nspace = "A24"\nbase = 0x300000\n')
    assert main(["crate", "--rig", str(crate_file), "list"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vmehil crate: error: board type 'scratch' (entry point 'acme_boards:no_such_factory' "
                          "of acme-boards") and err.count("\n") == 1


# ---- control objects (servo) ---------------------------------------------------------------------------
DAMPER = """
    from servo.control.objects import BaseControlObject, cfg_per_joint

    class Damper(BaseControlObject):
        name = "damper"

        def __init__(self, b):
            self.b = b

        @classmethod
        def from_config(cls, cfg, n, chain, period):
            obj = cls(cfg_per_joint(cfg, "b_nm_s_per_rad", n, 0.0))
            cfg.check_unknown()
            return obj

        def update(self, ctx, tau):
            return tau - self.b * ctx.omega
"""


def test_a_control_object_from_an_installed_package_joins_the_controller(install_distribution):
    install_distribution("acme-servo", {"acme_servo": DAMPER},
                         {"vmehil.control_objects": {"damper": "acme_servo:Damper.from_config"}})
    table = {"objects": ["pid", "damper"], "pid": {"kp": 0.0, "kpi": 0.0, "kv": 0.0, "kvi": 0.0},
             "damper": {"b_nm_s_per_rad": 2.0}}
    c = build_controller(table, unit_chain(1))
    assert [o.name for o in c.objects] == ["pid", "damper"]
    out = c.step(0, np.zeros(1), np.array([0.5]), np.zeros(1), np.zeros(1))
    np.testing.assert_allclose(out.torque, [-1.0])


def test_an_unknown_control_object_lists_the_known_ones(install_distribution):
    install_distribution("acme-servo", {"acme_servo": DAMPER},
                         {"vmehil.control_objects": {"damper": "acme_servo:Damper.from_config"}})
    with pytest.raises(ConfigError) as ei:
        build_controller({"objects": ["pid", "dampr"]}, unit_chain(1), source="rig.toml")
    assert ei.value.key == "objects[1]"
    assert "one of damper, friction_comp, gravity_comp, pid, torque_limit" in str(ei.value)
    assert CONTROL_OBJECTS.names() == ["damper", "friction_comp", "gravity_comp", "pid", "torque_limit"]


# ---- calibration procedures (vmehil) -------------------------------------------------------------------
def test_the_friction_procedure_comes_through_this_projects_own_entry_point():
    assert "friction" not in BUILTIN_PROCEDURES
    spec = PROCEDURES["friction"]
    assert spec.name == "friction" and not spec.in_all
    assert "friction" not in resolve_procedure_names("all")


def test_a_procedure_from_an_installed_package_can_be_calibrated_by_name(install_distribution):
    install_distribution("acme-cal", {"acme_cal": """
        from vmehil.calibration.base import ProcedureSpec

        class Zero:
            name, version, title = "zero", 1, "nothing"

        ZERO = ProcedureSpec("zero", Zero, order=5, help="calibrates nothing", in_all=False)
        MISNAMED = ProcedureSpec("other", Zero, order=5, help="x")
    """}, {"vmehil.calibration_procedures": {"zero": "acme_cal:ZERO", "misnamed": "acme_cal:MISNAMED"}})
    assert resolve_procedure_names("zero") == ["zero"]
    assert PROCEDURES["zero"].help == "calibrates nothing"
    with pytest.raises(PluginError, match="named 'misnamed' but its ProcedureSpec 'other'"):
        PROCEDURES["misnamed"]


def test_an_unknown_procedure_lists_the_known_ones():
    with pytest.raises(ValueError, match=r"unknown calibration procedure 'frobnicate'; choose from all, adc, "
                                         r"amplifier, dac, encoder, friction, home, pot$"):
        resolve_procedure_names("frobnicate")


def test_no_procedure_may_be_called_all(install_distribution):
    install_distribution("acme-cal", {"acme_cal": """
        from vmehil.calibration.base import ProcedureSpec
        ALL = ProcedureSpec("all", object, order=1, help="x")
    """}, {"vmehil.calibration_procedures": {"all": "acme_cal:ALL"}})
    with pytest.raises(PluginError, match="'all' means every procedure"):
        PROCEDURES["all"]


# ---- board types on the driver side (hal) and the emulators' under the same name -----------------------
ACME_ADC = """
    from emulators.adc import adc_factory
    from hal.board_types import BoardType

    # a commercial ADC of role "adc" (for the test, its driver and emulator are the reference ones)
    ACME_ADC = BoardType("adc", "Acme Corp", "ACME-3113", "acme-3113.pdf",
                         driver="hal.adc_dac.adc:AdcDriver", probe="hal.adc_dac.adc_regs:ADC_REGMAP")
    NOT_A_BOARD_TYPE = {"role": "adc"}

    def acme_emulator(name, cfg, ctx):
        return adc_factory(name, cfg, ctx)
"""


def _acme(install_distribution, drivers: dict[str, str] | None = None) -> None:
    install_distribution("acme-boards", {"acme_boards": ACME_ADC}, {
        "vmehil.board_drivers": drivers or {"acme-adc": "acme_boards:ACME_ADC"},
        "vmehil.board_types": {"acme-adc": "acme_boards:acme_emulator"}})


def test_a_board_type_from_an_installed_package_is_in_both_tables(install_distribution) -> None:
    from hal.board_types import BOARD_TYPES as DRIVER_BOARD_TYPES

    _acme(install_distribution)
    assert "acme-adc" in DRIVER_BOARD_TYPES.names() and "acme-adc" in BOARD_TYPES.names()
    assert DRIVER_BOARD_TYPES["acme-adc"].metadata() == {"vendor": "Acme Corp", "model": "ACME-3113",
                                                         "document": "acme-3113.pdf"}
    assert callable(BOARD_TYPES["acme-adc"])


def test_a_driver_side_entry_point_that_is_not_a_board_type_is_refused(install_distribution) -> None:
    from hal.board_types import BOARD_TYPES as DRIVER_BOARD_TYPES

    _acme(install_distribution, {"acme-adc": "acme_boards:NOT_A_BOARD_TYPE"})
    with pytest.raises(PluginError, match=r"board type 'acme-adc' .*not dict"):
        DRIVER_BOARD_TYPES["acme-adc"]


def test_an_installed_adc_board_type_is_wired_like_the_reference_adc(install_distribution, tmp_path, capsys) -> None:
    """jpl-arm with adc0 an ``acme-adc``: the rig's checks, the emulated crate and the joint I/O
    take it by its role, and `crate list` names its vendor, model and document."""
    from emulators.presets import resolve_rig
    from vmehil.rig_setup.system import build_emulated_rig

    _acme(install_distribution)
    text = resolve_rig("jpl-arm").read_text()
    head, sep, tail = text.partition('type = "adc"\nname = "adc0"')
    assert sep, "jpl-arm.toml's adc0 entry moved"
    rig_file = tmp_path / "jpl-arm.toml"
    rig_file.write_text(head + 'type = "acme-adc"\nname = "adc0"' + tail)
    system = build_emulated_rig(rig_file, seed=1, calibration=None)
    assert type(system.io.adc["adc0"]).__name__ == "AdcDriver"  # ACME_ADC's driver
    assert type(system.crate.board("adc0")).__name__ == "AdcBoard"
    system.io.read()  # the pots and tachs on adc0 are read through it
    assert main(["crate", "--rig", str(rig_file), "--json", "list"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert (rows["adc0"]["vendor"], rows["adc0"]["model"], rows["adc0"]["document"]) == (
        "Acme Corp", "ACME-3113", "acme-3113.pdf")
