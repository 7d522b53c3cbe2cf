"""jpl-arm wired onto one VMIVME-3113A (the ADC entry and pins the preset ``jpl-arm-vmic`` needs,
tests/support/vmivme3113a_preset.py): the rig builds, the joint I/O takes the board by its role and
reads every wired signal through its driver, `crate list` names it, and a short hold runs."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from hal.adc_dac.vmivme3113a import Vmivme3113aDriver
from servo.rig import load_rig
from tests.support.vmivme3113a_preset import jpl_arm_on_the_3113a
from vmehil.cli import main
from vmehil.rig_setup.real_bus import dry_pass
from vmehil.rig_setup.system import build_emulated_rig


@pytest.fixture
def rig_file(tmp_path: Path) -> Path:
    p = tmp_path / "jpl-arm-vmic.toml"
    p.write_text(jpl_arm_on_the_3113a(resolve_rig("jpl-arm").read_text()))
    return p


def test_the_joint_io_reads_the_arm_through_the_3113a_driver(rig_file: Path) -> None:
    system = build_emulated_rig(rig_file, seed=1, calibration=None)
    adc = system.io.adc["adc0"]
    assert isinstance(adc, Vmivme3113aDriver) and set(system.io.adc) == {"adc0"}
    m = system.io.read()
    nets = system.crate.signals
    for j in system.io.rig.joints:
        true_v = nets.get_analog(j.net("pot"))
        # the board's error (0.2 % gain, 6 mV offset), ½ LSB and a few noise sigmas (1 mV rms)
        assert m.pot_v[j.index] == pytest.approx(true_v * 1.002 + 0.006, abs=0.0025 + 0.005), j.name
    res = system.io.resolution()
    assert res.pot_rad[0] == pytest.approx(0.0048828125 / 3.370407819346141)  # one ±10 V code over j1's pot gradient


def test_crate_list_names_the_vmic_board(rig_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["crate", "--rig", str(rig_file), "--json", "list"]) == 0
    rows = {r["name"]: r for r in json.loads(capsys.readouterr().out)}
    assert (rows["adc0"]["vendor"], rows["adc0"]["model"], rows["adc0"]["document"]) == (
        "VMIC", "VMIVME-3113A", "docs/boards/vmivme-3113a.md")
    assert "adc1" not in rows


def test_a_one_second_hold_on_the_3113a_ends_in_a_verified_stop_with_the_joints_held(rig_file: Path) -> None:
    summary = rig_file.parent / "hold.json"
    assert main(["run", "--rig", str(rig_file), "--motion", "none", "--duration", "1", "--json", str(summary),
                 "--quiet"]) == 0
    report = json.loads(summary.read_text())
    assert (report["final_stop"]["reason"], report["final_stop"]["verified"]) == ("end", True)
    # README: the uncalibrated pots' 0.3 % bow leaves about 1° at each joint; a wrong range,
    # format or channel on this board would leave tens of degrees or trip a stop
    errors = np.array([j["final_error_deg"] for j in report["joints"]])
    assert np.all(np.abs(errors) < 2.0), errors


def test_adc_noise_on_a_pot_of_the_3113a_is_caught_by_the_watchdog(rig_file: Path) -> None:
    # --fault adc_noise acts on a board of the ADC role: 50 mV rms (≈ 10 codes) on j1's pot channel
    summary = rig_file.parent / "noise.json"
    main(["run", "--rig", str(rig_file), "--motion", "none", "--duration", "1", "--quiet", "--json", str(summary),
          "--fault", "adc_noise@0.2:joint=j1,signal=pot,rms_v=0.05"])
    report = json.loads(summary.read_text())
    assert [(f["cause"], f["joint"]) for f in report["faults"]] == [("position_mismatch", "j1")]
    assert report["faults"][0]["time_s"] >= 0.2
    assert report["final_stop"]["verified"]


def test_the_dry_pass_identifies_the_3113a_by_its_id_register(rig_file: Path) -> None:
    system = build_emulated_rig(rig_file, seed=1, calibration=None)
    checks = {c.name: c for c in dry_pass(system.crate, system.rig)}
    assert all(c.ok for c in checks.values()), [c.detail for c in checks.values() if not c.ok]
    assert checks["adc0"].detail.startswith("ID 0x1100")  # docs/boards/vmivme-3113a.md


def test_a_reference_adc_where_the_rig_names_a_3113a_is_refused_naming_both(tmp_path: Path) -> None:
    system = build_emulated_rig(None, seed=1)  # jpl-arm: the reference ADC at 0x6000
    text = resolve_rig("jpl-arm").read_text().replace('type = "adc"\nname = "adc0"',
                                                      'type = "vmivme-3113a"\nname = "adc0"')
    path = tmp_path / "wrong.toml"
    path.write_text(text)
    checks = {c.name: c for c in dry_pass(system.crate, load_rig(path))}
    assert not checks["adc0"].ok
    assert "ID reads 0xAD16" in checks["adc0"].detail
    assert "the rig file names type vmivme-3113a (VMIVME-3113A by VMIC, docs/boards/vmivme-3113a.md, ID 0x1100)" \
        in checks["adc0"].detail
    assert "the slot holds type adc (ADC16-REF" in checks["adc0"].detail


def test_calibrate_adc_fits_the_3113a_from_its_references_and_the_store_loads_back(
        rig_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from vmehil.calibration.store import load_store

    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "cal"))
    assert main(["calibrate", "adc", "--rig", str(rig_file)]) == 0
    path = tmp_path / "cal" / "jpl-arm.toml"
    system = build_emulated_rig(rig_file, seed=1, calibration=None)
    store = load_store(path, system.io.rig, bus=system.crate)  # checks the ID register: 0x1100
    cal = store.board_calibration("adc0")
    assert cal is not None and cal.channels == 64
    # the preset's board error: 6 mV offset, +0.2 % gain (within noise and quantization)
    assert cal.offset_v[0] == pytest.approx(0.006, abs=0.002)
    assert cal.gain[0] == pytest.approx(1.002, abs=0.001)
