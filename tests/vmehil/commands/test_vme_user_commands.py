"""``vmehil crate --bus vme_user:DIR`` and ``vmehil run --bus vme_user:DIR`` on the FUSE stand-in
for /dev/bus/vme, whose boards are an emulated rig's crate (real system calls, emulated boards)."""

from __future__ import annotations

import json
import sys
from collections.abc import Iterator
from io import StringIO
from pathlib import Path

import pytest

from hal.vme import AddressSpace, Width
from servo.rig import load_rig
from servo.settings import servo_settings
from tests.support.vme_fuse import MountedVmeUser, fuse_unavailable
from vmehil.cli import build_parser, main
from vmehil.commands.run_real import run_on_real_bus
from vmehil.rig_setup.system import EmulatedRig, build_emulated_rig


@pytest.fixture
def rig_on_fuse(tmp_path: Path) -> Iterator[tuple[EmulatedRig, str]]:
    why = fuse_unavailable()
    if why:
        pytest.skip(f"FUSE stand-in cannot be mounted: {why}")
    system = build_emulated_rig(None, seed=1)
    with MountedVmeUser(system.crate, tmp_path) as fs:
        yield system, f"vme_user:{fs.dir}"


def test_crate_list_dry_passes_every_board(rig_on_fuse, capsys) -> None:
    _, bus = rig_on_fuse
    assert main(["crate", "--bus", bus, "--json", "list"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert {b["name"] for b in out["boards"]} >= {"adc0", "dac0", "pio0", "quad0"}
    assert all(b["ok"] for b in out["boards"]) and any("ID 0xAD16" in b["detail"] for b in out["boards"])
    assert len(out["windows"]) == 4


def test_crate_list_on_the_wrong_rig_fails(rig_on_fuse, capsys) -> None:
    system, bus = rig_on_fuse
    system.crate.board("adc0").inject("removed")  # the board is not in the crate
    assert main(["crate", "--bus", bus, "list"]) == 1
    assert "adc0" in capsys.readouterr().out


def test_crate_list_refuses_a_wrong_board_in_a_slot_naming_both(rig_on_fuse, tmp_path, capsys) -> None:
    from tests.vmehil.test_dry_pass_identifies_boards import swapped_adc0_dac0

    _, bus = rig_on_fuse
    rig_file = swapped_adc0_dac0(tmp_path)  # the rig file has adc0 and dac0 the other way round
    assert main(["crate", "--bus", bus, "--rig", str(rig_file), "--json", "list"]) == 1
    boards = {b["name"]: b for b in json.loads(capsys.readouterr().out)["boards"]}
    assert not boards["adc0"]["ok"] and (boards["adc0"]["vendor"], boards["adc0"]["model"]) == (
        "vmehil (reference design)", "ADC16-REF")
    assert ("the rig file names type adc (ADC16-REF" in boards["adc0"]["detail"]
            and "the slot holds type dac (DAC8-REF" in boards["adc0"]["detail"])
    assert main(["run", "--bus", bus, "--rig", str(rig_file)]) == 1
    err = capsys.readouterr().err
    assert "dry pass failed" in err and "ID reads 0xDA08" in err and "the slot holds type dac" in err


def test_crate_read_write_and_shell(rig_on_fuse, capsys, monkeypatch) -> None:
    system, bus = rig_on_fuse
    assert main(["crate", "--bus", bus, "write", "A24", "0x200000", "0xBEEF"]) == 0
    assert system.crate.read(0x200000, space=AddressSpace.A24, width=Width.D16) == 0xBEEF
    assert main(["crate", "--bus", bus, "read", "A24", "0x200000"]) == 0
    assert "0xBEEF" in capsys.readouterr().out
    monkeypatch.setattr(sys, "stdin", StringIO("read A16 0x6000; counters\n"))
    assert main(["crate", "--bus", bus, "shell"]) == 1  # counters: not on a real bus
    out = capsys.readouterr().out
    assert "0xAD16" in out and "no access counters" in out


def test_run_without_the_flag_is_a_dry_run_that_leaves_everything_off(rig_on_fuse, capsys) -> None:
    system, bus = rig_on_fuse
    assert main(["run", "--bus", bus]) == 0
    err = capsys.readouterr().err
    assert "dry pass: adc0" in err and "dry run only" in err
    assert not any(system.crate.signals.get_digital(j.net("amp_enable"))
                   for j in system.rig.joints if "amp_enable" in j.wiring)


def test_run_refuses_a_crate_unlike_the_rig(rig_on_fuse, capsys) -> None:
    system, bus = rig_on_fuse
    system.crate.board("quad1").inject("removed")
    assert main(["run", "--bus", bus, "--enable-amplifiers"]) == 1
    assert "dry pass failed" in capsys.readouterr().err


def test_run_with_the_flag_runs_the_loop_and_ends_safe(rig_on_fuse, capsys) -> None:
    """The loop on the real-bus path; the bus's clock is the crate's (the drivers' waits must pass
    in the boards' time), the pacing the wall clock's."""
    system, bus = rig_on_fuse
    args = build_parser().parse_args(["run", "--bus", bus, "--enable-amplifiers", "--duration", "0.1"])
    code = run_on_real_bus(args.options(args), system.rig, servo_settings(system.rig),
                           clock=system.crate.now,
                           sleep=system.crate.delay)
    err = capsys.readouterr().err
    assert "amplifiers enabled" in err, err
    assert code in (0, 1)  # the plant does not move here (no harness steps): a fault stop is allowed
    s = system.crate.signals
    for j in system.rig.joints:
        if "amp_enable" in j.wiring:
            assert s.get_digital(j.net("amp_enable")) is False
        if "pwm" in j.wiring:
            assert s.get_analog(j.net("pwm")) == 0.0


def test_a_real_bus_run_refuses_what_needs_the_emulated_rig_in_one_line_before_opening_the_bus(tmp_path,
                                                                                                  capsys) -> None:
    # `--bus vme_user --enable-amplifiers` silently ignored --fault, --mavlink, --console, --vision
    missing = tmp_path / "no-such-bus"  # never opened: the refusal comes first
    assert main(["run", "--bus", f"vme_user:{missing}", "--enable-amplifiers", "--fault", "pot_open:joint=j1",
                 "--console", "pty:" + str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--fault/--faults" in err[0] and "--console" in err[0], err


def test_a_real_bus_run_loads_and_checks_the_calibration_as_the_emulated_run_does(rig_on_fuse, tmp_path,
                                                                                  capsys) -> None:
    # a calibration whose amplifier gain is NaN: refused on the emulated path, used on the real one
    from vmehil.calibration.store import CalibrationStore, JointCal

    system, bus = rig_on_fuse
    store = CalibrationStore.empty(system.rig)
    store.joints["j1"] = {"amplifier": JointCal("amplifier", 1, "2026-12-03", {"gain_a_per_v": 3.0, "offset_a": 0.0})}
    cal = store.save(tmp_path / "cal.toml")
    cal.write_text(cal.read_text().replace("gain_a_per_v = 3.0", "gain_a_per_v = nan"))
    assert main(["run", "--bus", bus, "--enable-amplifiers", "--calibration", str(cal)]) == 2
    assert "gain_a_per_v = nan: expected a finite number" in capsys.readouterr().err
    assert not any(system.crate.signals.get_digital(j.net("amp_enable"))
                   for j in system.rig.joints if "amp_enable" in j.wiring)


def test_a_real_bus_run_writes_the_same_json_and_report_as_the_emulated_run(rig_on_fuse, tmp_path, capsys) -> None:
    system, bus = rig_on_fuse
    out, rep = tmp_path / "run.json", tmp_path / "report"
    args = build_parser().parse_args(["run", "--bus", bus, "--enable-amplifiers", "--duration", "0.1",
                                      "--json", str(out), "--report", str(rep)])
    code = run_on_real_bus(args.options(args), system.rig, servo_settings(system.rig),
                           clock=system.crate.now, sleep=system.crate.delay)
    assert code in (0, 1)  # the plant does not move here (no harness steps): a fault stop is allowed
    summary = json.loads(out.read_text())
    assert summary["rig"] == system.rig.name and summary["final_stop"]["verified"] is True
    assert [j["name"] for j in summary["joints"]] == [j.name for j in system.rig.joints]
    # issue #29 on a real rig: a category (1 for the end, 0 for a fault) and the 2 s after the stop
    # read from the sensors (no plant truth here: excursion_deg is the sensors' figure)
    stop, names = summary["final_stop"], [j.name for j in system.rig.joints]
    assert stop["category"] in (0, 1) and stop["tick"] >= summary["ticks"] + 250
    assert list(stop["excursion_sensor_deg"]) == names and stop["excursion_deg"] == stop["excursion_sensor_deg"]
    assert (rep / "summary.md").exists() and any(rep.glob("*.png"))


# ---- jpl-arm-vmic: the VMIC boards on the vme_user path --------------------------------------

def _without_the_vision_link(tmp_path: Path) -> Path:
    """jpl-arm-vmic without its SBS 617 entry: what a user runs on a real bus (the 617 is a PCI
    card vme_user cannot reach; nothing on a real bus uses the vision link)."""
    from emulators.presets import resolve_rig

    text = resolve_rig("jpl-arm-vmic").read_text()
    start = text.index('[[crate.board]]\ntype = "sbs617"')
    end = text.index("[[crate.board]]", start + 1)
    path = tmp_path / "jpl-arm-vmic-no-link.toml"
    path.write_text(text[:start] + text[end:])
    return path


@pytest.fixture
def vmic_on_fuse(tmp_path: Path) -> Iterator[tuple[EmulatedRig, str]]:
    from emulators.presets import resolve_rig

    why = fuse_unavailable()
    if why:
        pytest.skip(f"FUSE stand-in cannot be mounted: {why}")
    system = build_emulated_rig(resolve_rig("jpl-arm-vmic"), seed=1, calibration=None)
    with MountedVmeUser(system.crate, tmp_path / "fs") as fs:
        yield system, f"vme_user:{fs.dir}"


def test_crate_list_on_the_vmic_rig_identifies_each_vme_board_and_refuses_the_pci_card(vmic_on_fuse,
                                                                                        capsys) -> None:
    _, bus = vmic_on_fuse
    assert main(["crate", "--bus", bus, "--rig", "jpl-arm-vmic", "--json", "list"]) == 1
    boards = {b["name"]: b for b in json.loads(capsys.readouterr().out)["boards"]}
    assert [n for n, b in boards.items() if not b["ok"]] == ["vision-link"]
    assert boards["adc0"]["detail"].startswith("ID 0x1100") and boards["adc0"]["model"] == "VMIVME-3113A"
    assert boards["dac0"]["detail"].startswith("no ID register (VMIVME-4116); CSR 0x")
    assert boards["dio0"]["detail"].startswith("BID 0x2536") and boards["dio0"]["vendor"] == "VMIC"
    assert boards["vision-link"]["detail"].startswith("a PCI card in the host, not a VME board")


def test_run_on_the_vmic_rig_refuses_the_pci_card_in_one_line(vmic_on_fuse, capsys) -> None:
    system, bus = vmic_on_fuse
    assert main(["run", "--bus", bus, "--rig", "jpl-arm-vmic", "--enable-amplifiers"]) == 1
    refusals = [x for x in capsys.readouterr().err.splitlines() if "dry pass failed" in x]
    assert len(refusals) == 1
    assert refusals[0].startswith("run: dry pass failed, nothing enabled: vision-link (sbs617 A32 0x80000000): "
                                  "a PCI card in the host")
    assert "use a rig file without it" in refusals[0] and "adc0" not in refusals[0]
    assert not any(system.crate.signals.get_digital(j.net("amp_enable")) for j in system.rig.joints)


def test_the_vmic_rig_without_the_vision_link_dry_runs_on_vme_user(vmic_on_fuse, tmp_path, capsys) -> None:
    system, bus = vmic_on_fuse
    rig = _without_the_vision_link(tmp_path)
    assert main(["crate", "--bus", bus, "--rig", str(rig), "list"]) == 0
    # the bus on the crate's clock: the 3113A's first autoscan, which its driver waits for when it
    # opens, ends in the boards' time, which passes in the stand-in only when the bus waits on it
    args = build_parser().parse_args(["run", "--bus", bus, "--rig", str(rig)])
    spec = load_rig(rig)
    assert run_on_real_bus(args.options(args), spec, servo_settings(spec), clock=system.crate.now,
                           sleep=system.crate.delay) == 0
    err = capsys.readouterr().err
    assert "dry pass: adc0     vmivme-3113a A16 0x8500: ID 0x1100" in err and "dry run only" in err
    s = system.crate.signals
    assert not any(s.get_digital(j.net("amp_enable")) for j in system.rig.joints)
    assert system.crate.boards["dac0"].converter == [0x8000] * 8  # the start-up stop: every DAC code 0 V


def test_a_reference_adc_where_the_rig_names_a_3113a_is_refused_on_vme_user_naming_both(rig_on_fuse, tmp_path,
                                                                                       capsys) -> None:
    from emulators.presets import resolve_rig

    _, bus = rig_on_fuse  # jpl-arm's crate: the reference ADC at A16 0x6000
    rig = tmp_path / "wrong.toml"
    rig.write_text(resolve_rig("jpl-arm").read_text().replace('type = "adc"\nname = "adc0"',
                                                             'type = "vmivme-3113a"\nname = "adc0"'))
    assert main(["crate", "--bus", bus, "--rig", str(rig), "--json", "list"]) == 1
    adc0 = next(b for b in json.loads(capsys.readouterr().out)["boards"] if b["name"] == "adc0")
    assert not adc0["ok"] and adc0["detail"] == (
        "ID reads 0xAD16, the rig's vmivme-3113a has 0x1100: the rig file names type vmivme-3113a (VMIVME-3113A by "
        "VMIC, docs/boards/vmivme-3113a.md, ID 0x1100); the slot holds type adc (ADC16-REF by vmehil (reference "
        "design), docs/boards/adc.md, ID 0xAD16)")
