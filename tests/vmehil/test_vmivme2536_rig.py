"""The VMIVME-2536 in the arm's role: jpl-arm with its digital lines moved from the reference PIO
boards to one VMIVME-2536 (the preset jpl-arm-vmic's wiring, the snippet below), the hand's
H-bridge kept on the reference PIO (the 2536 has no PWM timer). The rig loads, the emulated rig
builds, the servo's joint I/O drives the lines through the 2536 driver, and a stop leaves every
enable and brake line low on the emulated boards (their nets, not a flag)."""

from __future__ import annotations

import copy
import tomllib

import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError, ConfigTable
from hal.pio import Vmi2536Driver
from servo.rig import WATCHDOG_NET, rig_from_table
from tests.support.boards import assert_boards_safe
from vmehil.fault_scenarios.injection import check_rig, parse_fault_spec
from vmehil.rig_setup.system import build_emulated_rig

#: what the preset takes for the 2536 (crate slot and wiring); the hand's lines stay on pio0
SNIPPET = """
[[crate.board]]
type = "vmivme-2536"
name = "dio0"          # VMIC VMIVME-2536: OUT0-5 enables j1-j6, OUT6-11 fault resets j1-j6,
slot = 10              # OUT12-15 holding brakes j2, j3, j4, j6, OUT16 watchdog; IN0-5 faults j1-j6
space = "A16"
base = 0xFF00          # the EPICS support's default base (jumpers)

[rig.watchdog]
line = "dio0:OUT16"

[rig.readback]         # each enable and the watchdog wired back into a spare input: the 2536
"dio0:OUT0" = "dio0:IN16"    # cannot read its outputs' wires (OUTPUT reads the latch)
"dio0:OUT1" = "dio0:IN17"
"dio0:OUT2" = "dio0:IN18"
"dio0:OUT3" = "dio0:IN19"
"dio0:OUT4" = "dio0:IN20"
"dio0:OUT5" = "dio0:IN21"
"dio0:OUT16" = "dio0:IN22"

[wiring.j1]
amp_enable = "dio0:OUT0"
amp_fault = "dio0:IN0"
amp_reset = "dio0:OUT6"
[wiring.j2]
amp_enable = "dio0:OUT1"
amp_fault = "dio0:IN1"
amp_reset = "dio0:OUT7"
holding_brake = "dio0:OUT12"
[wiring.j3]
amp_enable = "dio0:OUT2"
amp_fault = "dio0:IN2"
amp_reset = "dio0:OUT8"
holding_brake = "dio0:OUT13"
[wiring.j4]
amp_enable = "dio0:OUT3"
amp_fault = "dio0:IN3"
amp_reset = "dio0:OUT9"
holding_brake = "dio0:OUT14"
[wiring.j5]
amp_enable = "dio0:OUT4"
amp_fault = "dio0:IN4"
amp_reset = "dio0:OUT10"
[wiring.j6]
amp_enable = "dio0:OUT5"
amp_fault = "dio0:IN5"
amp_reset = "dio0:OUT11"
holding_brake = "dio0:OUT15"
"""


def _vmic_rig_data() -> dict:
    with open(resolve_rig("jpl-arm"), "rb") as f:
        data = tomllib.load(f)
    snippet = tomllib.loads(SNIPPET)
    data = copy.deepcopy(data)
    data["crate"]["board"] = [b for b in data["crate"]["board"] if b["name"] != "pio1"] + snippet["crate"]["board"]
    data["rig"]["watchdog"]["line"] = snippet["rig"]["watchdog"]["line"]
    data["rig"]["readback"] = snippet["rig"]["readback"]
    for j in data["joint"]:
        # pio1's other lines (the hand's tactile switches) go with it, as on jpl-arm-vmic (no switches)
        j["wiring"] = {k: v for k, v in j["wiring"].items() if not str(v).startswith("pio1:")}
        j["wiring"].update(snippet["wiring"].get(j["name"], {}))
    return data


def _spec(data: dict):
    return rig_from_table(ConfigTable(data, "jpl-arm-vmic (test)"), "jpl-arm-vmic.toml")


@pytest.fixture(scope="module")
def system():
    s = build_emulated_rig(_spec(_vmic_rig_data()), seed=0)
    yield s
    s.close()


def test_the_rig_builds_with_the_2536_driver_for_the_digital_lines_and_the_pio_for_the_hand(system) -> None:
    assert isinstance(system.io.pio["dio0"], Vmi2536Driver)
    assert type(system.io.pio["pio0"]).__name__ == "PioDriver"
    assert "pio1" not in system.io.pio
    assert system.crate.boards["dio0"].describe()["model"] == "VMIVME-2536"


def test_enable_drives_the_2536_lines_and_a_stop_leaves_them_low(system) -> None:
    s = system.crate.signals
    nets = [j.net("amp_enable") for j in system.rig.joints]
    assert not any(s.get_digital(n) for n in nets)  # built: every enable low
    system.io.enable(True)
    system.io.write_torque([0.0] * system.rig.n_joints)  # releases the brakes, feeds the watchdog
    assert all(s.get_digital(n) for n in nets)
    assert s.get_digital("j2.holding_brake") and s.get_digital(WATCHDOG_NET)
    assert system.io.safe_stop() == []
    assert not any(s.get_digital(n) for n in nets)
    assert not any(s.get_digital(f"j{i}.holding_brake") for i in (2, 3, 4, 6))
    assert not s.get_digital(WATCHDOG_NET)
    assert_boards_safe(system)


def test_the_readback_inputs_sit_on_the_enables_nets_and_reach_the_driver(system) -> None:
    lines = system.crate.boards["dio0"].describe()["lines"]
    assert (lines["IN16"], lines["IN21"], lines["IN22"]) == ("j1.amp_enable", "j6.amp_enable", WATCHDOG_NET)
    drv = system.io.pio["dio0"]
    assert drv.read_pins("OUT") & 0x3F == 0  # every enable's wire low (through IN16..IN21)


def test_a_stop_reports_a_stuck_high_enable_seen_through_its_readback_input() -> None:
    s = build_emulated_rig(_spec(_vmic_rig_data()), seed=0)
    try:
        s.crate.boards["dio0"].inject("line_stuck", line="OUT2", level=True)  # j3's enable
        failures = s.io.safe_stop()
        assert s.crate.signals.get_digital("j3.amp_enable") is True  # the wire really is high
        # the enable write's own check and the stop's read-back both see the wire (through IN18)
        assert failures == [
            "j3: output line(s) do not follow their latch: j3.amp_enable (latch 0, pin 1); the line is stuck or "
            "shorted — check the wiring and the load before re-enabling",
            "j3: amplifier enable dio0:OUT2 still reads high",
        ]
    finally:
        s.close()


def test_the_readback_refuses_an_input_in_use_and_a_board_that_cannot_take_it() -> None:
    data = _vmic_rig_data()
    data["rig"]["readback"] = {"dio0:OUT0": "dio0:IN3"}  # j4's fault input
    with pytest.raises(ConfigError, match=r"a free line \(dio0:IN3 is in use\)"):
        _spec(data)
    data = _vmic_rig_data()
    data["rig"]["readback"] = {"pio0:PC7": "pio0:PB7"}  # the reference PIO reads its pins itself
    with pytest.raises(ConfigError, match="a board that reads back through an input"):
        _spec(data)


def test_an_amplifier_fault_line_on_the_2536_reads_as_the_joints_fault(system) -> None:
    system.crate.signals.set_digital("j4.amp_fault", True)
    try:
        assert list(system.io.read().fault) == [0, 0, 0, 1, 0, 0, 0]
    finally:
        system.crate.signals.set_digital("j4.amp_fault", False)


def test_the_pio_line_faults_apply_to_a_2536_pin() -> None:
    spec = _spec(_vmic_rig_data())
    check_rig([parse_fault_spec("enable_stuck_high:joint=j1"), parse_fault_spec("amp_fault_line:joint=j2")], spec)


def test_the_wiring_checks_refuse_a_line_the_2536_does_not_have_and_pwm_on_it() -> None:
    data = _vmic_rig_data()
    data["joint"][0]["wiring"]["amp_enable"] = "dio0:PA0"
    with pytest.raises(ConfigError, match=r"a line of the vmivme-2536 board \(IN0..IN31, OUT0..OUT31\)"):
        _spec(data)
    data = _vmic_rig_data()
    data["joint"][6]["wiring"]["pwm"] = "dio0:PWM"
    with pytest.raises(ConfigError, match="a PIO board with a PWM timer"):
        _spec(data)
