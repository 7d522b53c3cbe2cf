"""The amplifiers against their spec, docs/boards/amplifiers.md: the doc's worked examples checked
both ways — the drivers (hal.amplifiers, current/volts → DAC code, PWM ticks, line levels) and the
power-stage model (emulators/plant/amplifier.py, DAC volts/duty/lines → current/voltage) — and
the golden bus traces of the drivers' enable, disable and fault operations, written by hand from
the doc's cycle table (PIO at 0x4000: DATA_A/B/C 0x06..0x08, PIN_A/B/C 0x0A..0x0C, PWM_DUTY 0x1C;
DAC at 0x7000: DATA0 0x10, UPDATE 0x04).

The drivers run on a RecordingBus forwarding to an emulated crate with the PIO and DAC boards
installed, wired like the jpl-arm (joint 1 and the hand).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from emulators.crate import Crate
from emulators.dac import DacBoard
from emulators.pio import PioBoard
from emulators.plant.amplifier import AmpArrays, prepare_drive
from hal.adc_dac import DacDriver
from hal.amplifiers import AmplifierFault, HBridgeAmp, HBridgeConfig, LinearAmp, LinearAmpConfig
from hal.pio import PioDriver
from tests.support import REPO
from tests.support.bus_trace import RecordingBus

DOC = REPO / "docs" / "boards" / "amplifiers.md"
PINS = {"j1.amp_enable": "PA0", "j1.amp_fault": "PB0", "j1.amp_reset": "PC0", "hand.direction": "PA6",
        "hand.brake": "PA7", "hand.amp_enable": "PC7", "hand.amp_fault": "PB6", "hand.amp_reset": "PC6"}
OUTPUTS = ["j1.amp_enable", "j1.amp_reset", "hand.direction", "hand.brake", "hand.amp_enable", "hand.amp_reset"]


def _doc_table(heading: str) -> list[dict[str, str]]:
    """The rows of the first table after the doc's ``heading`` line (minus signs as ASCII)."""
    lines = DOC.read_text().splitlines()
    i = lines.index(heading)
    while not lines[i].startswith("|"):
        i += 1
    head = [c.strip() for c in lines[i].strip("|").split("|")]
    rows = []
    i += 2
    while i < len(lines) and lines[i].startswith("|"):
        cells = [c.strip().replace("−", "-") for c in lines[i].strip("|").split("|")]
        rows.append(dict(zip(head, cells, strict=True)))
        i += 1
    assert rows, f"no table after {heading!r}"
    return rows


@dataclass
class Rig:
    crate: Crate
    bus: RecordingBus
    pio: PioDriver
    dac: DacDriver


@pytest.fixture
def rig() -> Rig:
    crate = Crate("amp-trace")
    crate.install(PioBoard("pio0", lines={pin: net for net, pin in PINS.items()}, pwm_net="hand.pwm"),
                  base=0x4000, space="A16", slot=4)
    crate.install(DacBoard("dac0", wiring={0: "j1.amp_command"}), base=0x7000, space="A16", slot=5)
    bus = RecordingBus(crate)
    pio = PioDriver(bus, 0x4000, lines=PINS)
    pio.configure(outputs=OUTPUTS)
    pio.set_pwm_period(50e-6)
    pio.pwm_enable(True)
    dac = DacDriver(bus, 0x7000, clamp=True)
    bus.clear()
    return Rig(crate, bus, pio, dac)


def _linear(r: Rig) -> LinearAmp:
    cfg = LinearAmpConfig(gain_a_per_v=3.0, current_limit_a=30.0, monitor_v_per_a=1 / 3, dac_channel=0,
                          enable_line="j1.amp_enable", fault_line="j1.amp_fault", reset_line="j1.amp_reset")
    return LinearAmp(cfg, r.dac, r.pio)


def _hand(r: Rig) -> HBridgeAmp:
    cfg = HBridgeConfig(supply_v=24.0, direction_line="hand.direction", brake_line="hand.brake",
                        fault_line="hand.amp_fault", reset_line="hand.amp_reset", enable_line="hand.amp_enable")
    return HBridgeAmp(cfg, r.pio)


def _plant_amps() -> AmpArrays:
    """Joint 0: the doc's linear amplifier (3 A/V, 30 A); joint 1: its H-bridge (24 V, dead time
    1 µs at 20 kHz = 0.02 of the period). Thermal and monitor values play no part here."""
    one = np.ones(2)
    return AmpArrays(
        is_lin=np.array([True, False]), gain=np.array([3.0, 0.0]), bw_rad_s=one * 6283.0,
        lin_limit=np.array([30.0, 0.0]), lin_supply=np.array([28.0, 0.0]), lin_monitor=one / 3,
        lin_monitor_offset=one * 0.0, lin_monitor_noise=one * 0.0, sat_fault_s=one * 0.5,
        hb_supply=np.array([0.0, 24.0]), hb_deadtime_duty=np.array([0.0, 0.02]), hb_limit=one * 2.0,
        hb_trip=one * 4.0, hb_monitor=one * 2.5, hb_monitor_offset=one * 0.0, hb_monitor_noise=one * 0.0,
        i_cont=one * 10.0, tau_th=one * 20.0,
    )


# --- the doc's worked examples, both ways ----------------------------------------------------
def test_doc_linear_examples_driver_side_current_to_volts_and_dac_code(rig) -> None:
    amp = _linear(rig)
    for row in _doc_table("### Worked examples: linear amplifier"):
        current, volts, code = float(row["current asked (A)"]), float(row["command (V)"]), int(row["DAC code"], 16)
        assert amp.command_volts_for(current) == pytest.approx(volts, abs=1e-6), row
        rig.bus.clear()
        amp.set_current(current)
        assert rig.bus.trace() == [f"W A16 0x7010 D16 0x{code:04X}", "W A16 0x7004 D16 0x0001"], row


def test_doc_linear_examples_plant_side_dac_volts_to_current() -> None:
    amp = _plant_amps()
    rows = _doc_table("### Worked examples: linear amplifier")
    for row in rows:  # the DAC's ideal output for the code (docs/boards/dac.md) drives the amplifier
        code = int(row["DAC code"], 16)
        assert -10.0 + code * 20.0 / 4096 == pytest.approx(float(row["volts out (V)"]), abs=1e-6), row
    for v_in, i_out in [(float(r["volts out (V)"]), float(r["current (A)"])) for r in rows] + [
            (float(r["amplifier input (V)"]), float(r["current (A)"]))
            for r in _doc_table("### Worked examples: the amplifier's own limit")]:
        drv = prepare_drive(amp, np.array([v_in, 0.0]), np.array([True, False]), np.zeros(2), np.zeros(2, bool),
                            np.zeros(2, bool))
        assert drv.lin_on[0] and drv.i_ref[0] == pytest.approx(i_out, abs=1e-5), (v_in, i_out)


def test_doc_hbridge_examples_driver_side_volts_to_duty_ticks_and_lines(rig) -> None:
    hand = _hand(rig)
    for row in _doc_table("### Worked examples: H-bridge"):
        assert hand.set_voltage(float(row["volts asked (V)"])) == pytest.approx(float(row["duty"])), row
        writes = {c.address: c.value for c in rig.bus.cycles if c.op == "W"}  # the last of each
        assert writes[0x401C] == int(row["PWM_DUTY"]), row
        assert bool(writes[0x4006] >> 6 & 1) is (row["direction line"] == "high"), row  # PA6
        assert bool(writes[0x4006] >> 7 & 1) is (row["brake line"] == "high"), row  # PA7
        assert rig.crate.signals.get_analog("hand.pwm") == pytest.approx(int(row["PWM_DUTY"]) / 500)


def test_doc_hbridge_examples_plant_side_duty_and_lines_to_bridge_volts() -> None:
    amp = _plant_amps()
    for row in _doc_table("### Worked examples: H-bridge"):
        duty = int(row["PWM_DUTY"]) / 500  # what the PIO's PWM output averages to
        drv = prepare_drive(amp, np.zeros(2), np.array([False, True]), np.array([0.0, duty]),
                            np.array([False, row["direction line"] == "high"]),
                            np.array([False, row["brake line"] == "high"]))
        assert drv.hb_v[1] == pytest.approx(float(row["bridge volts (V)"]), abs=1e-9), row


def test_plant_brake_shorts_the_winding_and_disable_coasts() -> None:
    amp = _plant_amps()
    duty, fwd = np.array([0.0, 0.5]), np.array([False, True])
    braking = prepare_drive(amp, np.zeros(2), np.array([False, True]), duty, fwd, np.array([False, True]))
    assert braking.hb_brake[1] and not braking.hb_drive[1] and braking.hb_v[1] == 0.0
    braking_disabled = prepare_drive(amp, np.zeros(2), np.array([False, False]), duty, fwd, np.array([False, True]))
    assert braking_disabled.hb_brake[1]  # the brake input works with the enable low (doc)
    coasting = prepare_drive(amp, np.zeros(2), np.array([False, False]), duty, fwd, np.zeros(2, bool))
    assert not coasting.hb_brake[1] and not coasting.hb_drive[1] and coasting.hb_v[1] == 0.0


# --- golden traces: enable, disable, fault --------------------------------------------------------
def test_linear_enable_command_and_disable_trace(rig) -> None:
    amp = _linear(rig)
    amp.enable()
    amp.set_current(2.0)
    amp.disable()
    assert rig.bus.trace() == [
        "W A16 0x4006 D8 0x01", "R A16 0x400A D8 0x01",  # PA0 high, read back
        "W A16 0x7010 D16 0x0889", "W A16 0x7004 D16 0x0001",  # 2 A = 2/3 V = 0x889, strobe channel 0
        "W A16 0x7010 D16 0x0800", "W A16 0x7004 D16 0x0001",  # disable: 0 V first
        "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # then PA0 low
    ]
    assert rig.crate.signals.get_digital("j1.amp_enable") is False


def test_linear_fault_read_and_reset_pulse_trace(rig) -> None:
    amp = _linear(rig)
    assert amp.faulted() is False
    rig.crate.signals.set_digital("j1.amp_fault", True)  # the amplifier latches a fault
    with pytest.raises(AmplifierFault, match="fault line"):
        amp.check()
    amp.clear_fault()
    assert rig.bus.trace() == [
        "R A16 0x4007 D8 0x00",  # DATA_B: PB0 is an input, its pin
        "R A16 0x4007 D8 0x01",
        "W A16 0x4008 D8 0x01", "R A16 0x400C D8 0x01",  # PC0 high
        "W A16 0x4008 D8 0x00", "R A16 0x400C D8 0x00",  # PC0 low
    ]


def test_hbridge_enable_drive_brake_disable_and_fault_trace(rig) -> None:
    hand = _hand(rig)
    hand.enable()
    hand.set_voltage(-6.0)
    hand.set_voltage(12.0)
    hand.brake()
    hand.disable()
    rig.crate.signals.set_digital("hand.amp_fault", True)
    assert hand.faulted() is True
    assert rig.bus.trace() == [
        "W A16 0x4008 D8 0x80", "R A16 0x400C D8 0x80",  # PC7: enable high
        "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # brake (PA7) low
        # −0.25: direction already low (reverse): 125 ticks at once, PA6 written low again, 125 ticks
        "W A16 0x401C D16 0x007D", "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00", "W A16 0x401C D16 0x007D",
        "W A16 0x4006 D8 0x00", "R A16 0x400A D8 0x00",  # brake low
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x40", "R A16 0x400A D8 0x40",  # reversal: duty 0, PA6 high
        "W A16 0x401C D16 0x00FA",  # 0.5: 250 ticks
        # brake: duty 0 (direction stays forward, PA6 written high again), then PA7 high
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0x40", "R A16 0x400A D8 0x40", "W A16 0x401C D16 0x0000",
        "W A16 0x4006 D8 0xC0", "R A16 0x400A D8 0xC0",
        # disable = coast (duty 0, brake low) then enable low
        "W A16 0x401C D16 0x0000", "W A16 0x4006 D8 0xC0", "R A16 0x400A D8 0xC0", "W A16 0x401C D16 0x0000",
        "W A16 0x4006 D8 0x40", "R A16 0x400A D8 0x40",
        "W A16 0x4008 D8 0x00", "R A16 0x400C D8 0x00",
        "R A16 0x4007 D8 0x40",  # DATA_B bit 6: PB6, the fault input, high
    ]
