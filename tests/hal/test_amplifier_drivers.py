"""The amplifier drivers (hal.amplifiers) on the emulated jpl-arm: current and torque commands,
enable, current monitor, fault line and reset; H-bridge duty, voltage, brake and coast."""

from __future__ import annotations

import pytest

from hal.amplifiers import AmplifierFault, HBridgeAmp, HBridgeConfig, LinearAmp, LinearAmpConfig
from vmehil.rig_setup.system import build_emulated_rig


def _advance(system, ticks: int) -> None:
    """Let the plant run ``ticks`` servo periods with whatever the boards command."""
    for _ in range(ticks):
        k = system.harness.exchanges
        system.crate.advance_to(k * system.period_ns)
        system.harness.step(system.rig.period_s, 0.0)
        system.harness.publish()


@pytest.fixture
def rig():
    system = build_emulated_rig(None, seed=4)
    yield system
    system.close()


def _linear_j1(system) -> LinearAmp:
    p, io = system.params[0], system.io
    cfg = LinearAmpConfig(gain_a_per_v=p.linear_amp.gain_a_per_v, current_limit_a=p.linear_amp.current_limit_a,
                          monitor_v_per_a=p.linear_amp.monitor_v_per_a, dac_channel=0, monitor_channel=0,
                          enable_line="j1.amp_enable", fault_line="j1.amp_fault", reset_line="j1.amp_reset")
    return LinearAmp(cfg, io.dac["dac0"], io.pio["pio0"], io.adc["adc1"])


def test_linear_amp_drives_current_read_back_on_the_monitor(rig) -> None:
    amp = _linear_j1(rig)
    amp.enable()
    volts = amp.set_current(2.0)
    assert volts == pytest.approx(2.0 / 3.0)
    _advance(rig, 3)
    assert amp.monitor_current() == pytest.approx(2.0, abs=0.05)  # uncalibrated ADC: ≈18 mA offset
    amp.disable()
    _advance(rig, 3)
    assert abs(amp.monitor_current()) < 0.05
    assert amp.set_current(100.0) == pytest.approx(30.0 / 3.0)  # clamped to the current limit


def test_linear_amp_fault_line_raises_and_reset_pulses(rig) -> None:
    amp = _linear_j1(rig)
    assert not amp.faulted()
    amp.check()
    rig.crate.board("pio0").inject("line_stuck", line="PB0", level=True)
    assert amp.faulted()
    with pytest.raises(AmplifierFault, match="fault line"):
        amp.check()
    amp.clear_fault()  # a pulse on PC0; the reset line ends low
    assert rig.crate.signals.get_digital("j1.amp_reset") is False


def _hand(system) -> HBridgeAmp:
    p, io = system.params[6], system.io
    cfg = HBridgeConfig(supply_v=p.hbridge.supply_v, direction_line="hand.direction", brake_line="hand.brake",
                        fault_line="hand.amp_fault", reset_line="hand.amp_reset", enable_line="hand.amp_enable",
                        monitor_channel=6, monitor_v_per_a=p.hbridge.monitor_v_per_a)
    io.pio["pio0"].pwm_enable(True)
    return HBridgeAmp(cfg, io.pio["pio0"], io.adc["adc1"])


def test_hbridge_duty_voltage_brake_and_coast(rig) -> None:
    hand = _hand(rig)
    sig = rig.crate.signals
    hand.enable()
    assert hand.set_voltage(-6.0) == pytest.approx(-0.25)
    assert sig.get_analog("hand.pwm") == pytest.approx(0.25, abs=1e-3)
    assert sig.get_digital("hand.direction") is False and sig.get_digital("hand.brake") is False
    _advance(rig, 3)
    assert hand.monitor_current() < -0.05  # current flows backwards
    hand.brake()
    assert sig.get_digital("hand.brake") is True and sig.get_analog("hand.pwm") == 0.0
    hand.coast()
    assert sig.get_digital("hand.brake") is False
    with pytest.raises(ValueError, match="outside"):
        hand.set_duty(1.5)
    assert not hand.faulted()
