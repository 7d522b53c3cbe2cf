"""`vmehil calibrate` end to end on the default rig (its preset wires the ADC references and the
DAC→ADC loopbacks the adc and dac procedures need)."""

from __future__ import annotations

import json

import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from vmehil.calibration.store import CalibrationMissingWarning, load_store, load_store_or_nominal
from vmehil.cli import main


def default_rig_with_references(tmp_path):
    """A copy of the jpl-arm preset, so that nothing the run writes lands beside the preset."""
    p = tmp_path / "jpl-arm.toml"
    p.write_text(resolve_rig("jpl-arm").read_text())
    return p


def test_calibrate_adc_dac_writes_a_file_the_drivers_load(tmp_path, capsys):
    rig_path = default_rig_with_references(tmp_path)
    out = tmp_path / "cal.toml"
    rc = main(["calibrate", "dac", "--rig", str(rig_path), "--out", str(out), "--json", str(tmp_path / "r.json")])
    assert rc == 0
    assert main(["calibrate", "adc", "--rig", str(rig_path), "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "procedure" in text and "pass" in text
    store = load_store(out, load_rig(rig_path))
    assert "adc1" in store.boards and "dac0" in store.boards  # the second run kept the first's tables
    assert json.loads((tmp_path / "r.json").read_text())["passed"] is True
    from vmehil.rig_setup.system import build_emulated_rig

    system = build_emulated_rig(load_rig(rig_path), calibration=out)
    assert system.io.calibration is not None


def test_calibrate_refuses_a_foreign_file_before_running(tmp_path, capsys):
    rig_path = default_rig_with_references(tmp_path)
    out = tmp_path / "cal.toml"
    out.write_text('[calibration]\nformat = "vmehil-calibration"\nformat_version = 1\nrig = "other"\ncrate = "x"\n')
    assert main(["calibrate", "adc", "--rig", str(rig_path), "--out", str(out)]) == 2
    assert "written for rig 'other'" in capsys.readouterr().err
    assert "rig = \"other\"" in out.read_text()


def test_an_operator_procedure_without_a_terminal_is_refused_in_one_line_before_anything_runs(tmp_path, monkeypatch,
                                                                                             capsys):
    # it ended "pot: EOFError: EOF when reading a line" after the adc, dac, encoder and amplifier
    # procedures had run on a built rig
    class NoTerminal:
        def isatty(self) -> bool:
            return False

    monkeypatch.setattr("sys.stdin", NoTerminal())
    out = tmp_path / "cal.toml"
    assert main(["calibrate", "all", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pot asks the operator" in err[0] and "--auto" in err[0]
    assert not out.exists()


def test_the_missing_calibration_warning_suggests_the_command_that_works_without_a_terminal(tmp_path):
    with pytest.warns(CalibrationMissingWarning, match="vmehil calibrate all --auto --rig jpl-arm"):
        load_store_or_nominal(tmp_path / "none.toml", load_rig(resolve_rig("jpl-arm")))


def test_a_joint_the_rig_does_not_have_is_bad_input(tmp_path, capsys):
    # the rig's joint check is an argument check: exit 2 with its text, never "unexpected" (3)
    out = tmp_path / "cal.toml"
    assert main(["calibrate", "friction", "--joint", "9", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err == "vmehil calibrate: error: rig jpl-arm has joints 1..7; there is no joint 9"
    assert not out.exists()
