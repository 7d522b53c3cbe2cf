"""The amplifier drivers' contract with the boards they drive (docs/boards/amplifiers.md, "Lines",
"Linear transconductance amplifier", "PWM H-bridge"), on recording stand-ins for the DAC, PIO and
ADC drivers: which call, with which values, in which order; what an unwired line does; the
error texts. Expected values are worked by hand from the doc's formulas. (The bus cycles of the
same operations on the emulated boards: test_amplifier_traces.py.)"""

from __future__ import annotations

import math

import pytest

from hal.amplifiers import AmplifierFault, HBridgeAmp, HBridgeConfig, LinearAmp, LinearAmpConfig
from hal.amplifiers.hbridge import duty_for_current
from hal.amplifiers.linear import clamp_current, command_volts


class Boards:
    """Stands in for the DAC, PIO and ADC drivers; records every call in order."""

    def __init__(self, lines: dict[str, bool] | None = None, volts: dict[int, float] | None = None) -> None:
        self.calls: list[tuple] = []
        self.lines = dict(lines or {})
        self.volts = dict(volts or {})

    # DacChannel
    def write_volts(self, *args: object, **kwargs: object) -> None:
        self.calls.append(("write_volts", args, kwargs))

    # DigitalLines / PwmLines
    def set_line(self, *args: object, **kwargs: object) -> None:
        self.calls.append(("set_line", args, kwargs))

    def get_line(self, *args: object, **kwargs: object) -> bool:
        self.calls.append(("get_line", args, kwargs))
        return self.lines[args[0]]  # type: ignore[index]

    def set_pwm(self, *args: object, **kwargs: object) -> None:
        self.calls.append(("set_pwm", args, kwargs))

    # AnalogInput
    def read_volts(self, *args: object, **kwargs: object) -> float:
        self.calls.append(("read_volts", args, kwargs))
        return self.volts[args[0]]  # type: ignore[index]


# --- linear transconductance amplifier -------------------------------------------------------
def _linear(boards: Boards | None = None, *, wired: bool = True, offset_a: float = 0.0) -> tuple[LinearAmp, Boards]:
    b = boards or Boards()
    cfg = LinearAmpConfig(gain_a_per_v=3.0, current_limit_a=30.0, monitor_v_per_a=0.5, dac_channel=2,
                          monitor_channel=5 if wired else None, enable_line="en" if wired else None,
                          fault_line="flt" if wired else None, reset_line="rst" if wired else None,
                          offset_a=offset_a)
    return LinearAmp(cfg, b, b if wired else None, b if wired else None), b


def test_linear_current_to_command_volts_clamps_then_removes_the_offset() -> None:
    assert clamp_current(31.0, 30.0) == 30.0 and clamp_current(-31.0, 30.0) == -30.0
    assert clamp_current(-12.5, 30.0) == -12.5
    assert command_volts(2.0, 3.0) == pytest.approx(2.0 / 3.0)  # offset 0 by default
    assert command_volts(2.0, 4.0, 0.4) == pytest.approx(0.4)  # (2 − 0.4) / 4
    amp, _ = _linear(offset_a=0.6)
    assert amp.command_volts_for(2.0) == pytest.approx(1.4 / 3.0)
    assert amp.command_volts_for(100.0) == pytest.approx(29.4 / 3.0)  # clamped to +30 A first
    assert amp.command_volts_for(-100.0) == pytest.approx(-30.6 / 3.0)


def test_linear_set_current_writes_the_channel_and_records_what_the_amplifier_will_set() -> None:
    amp, b = _linear(offset_a=0.6)
    assert amp.commanded_a == 0.0
    volts = amp.set_current(2.0)
    assert volts == pytest.approx(1.4 / 3.0)
    assert b.calls == [("write_volts", (2, volts), {"update": True})]
    assert amp.commanded_a == pytest.approx(2.0)
    b.calls.clear()
    volts = amp.set_current(-100.0, update=False)
    assert b.calls == [("write_volts", (2, volts), {"update": False})]
    assert amp.commanded_a == pytest.approx(-30.0)  # what the clamp let through


def test_linear_refuses_a_gain_or_monitor_scaling_that_is_not_positive() -> None:
    b = Boards()
    for gain, monitor in ((0.0, 0.5), (-3.0, 0.5), (3.0, 0.0), (3.0, -0.5)):
        cfg = LinearAmpConfig(gain_a_per_v=gain, current_limit_a=30.0, monitor_v_per_a=monitor, dac_channel=0)
        with pytest.raises(ValueError, match=r"^amplifier gain and monitor scaling must be positive$"):
            LinearAmp(cfg, b)
    cfg = LinearAmpConfig(gain_a_per_v=0.001, current_limit_a=30.0, monitor_v_per_a=0.001, dac_channel=0)
    assert LinearAmp(cfg, b).dac is b


def test_linear_enable_disable_and_fault_lines() -> None:
    amp, b = _linear(Boards(lines={"flt": True}))
    amp.enable()
    amp.enable(False)
    assert b.calls == [("set_line", ("en", True), {}), ("set_line", ("en", False), {})]
    b.calls.clear()
    amp.disable()  # the command to 0 A first, then the enable low
    assert b.calls == [("write_volts", (2, 0.0), {"update": True}), ("set_line", ("en", False), {})]
    assert amp.commanded_a == 0.0
    b.calls.clear()
    assert amp.faulted() is True
    with pytest.raises(AmplifierFault, match=r"^amplifier on DAC channel 2: fault line asserted; "
                                             r"find the cause, then clear_fault\(\)$"):
        amp.check()
    b.lines["flt"] = False
    assert amp.faulted() is False
    amp.check()
    assert b.calls == [("get_line", ("flt",), {})] * 4
    b.calls.clear()
    amp.clear_fault()  # a high pulse
    assert b.calls == [("set_line", ("rst", True), {}), ("set_line", ("rst", False), {})]


def test_linear_monitor_volts_to_amperes() -> None:
    amp, b = _linear(Boards(volts={5: 1.25}))
    assert amp.monitor_current() == pytest.approx(2.5)  # 1.25 V / 0.5 V/A
    assert b.calls == [("read_volts", (5,), {})]
    assert amp.monitor_to_current(-0.75) == pytest.approx(-1.5)


def test_linear_without_lines_or_monitor() -> None:
    amp, b = _linear(wired=False)
    with pytest.raises(ValueError, match=r"^this amplifier has no enable line wired$"):
        amp.enable()
    with pytest.raises(ValueError, match=r"^this amplifier has no fault-reset line wired$"):
        amp.clear_fault()
    with pytest.raises(ValueError, match=r"^this amplifier's current monitor is not wired to an ADC channel$"):
        amp.monitor_current()
    assert amp.faulted() is False
    amp.check()
    amp.disable()  # the command still goes to 0 A
    assert b.calls == [("write_volts", (2, 0.0), {"update": True})]
    # a PIO but no line named: the same refusals, no call to the PIO
    cfg = LinearAmpConfig(gain_a_per_v=3.0, current_limit_a=30.0, monitor_v_per_a=0.5, dac_channel=1)
    b = Boards()
    amp = LinearAmp(cfg, b, b, b)
    for call in (amp.enable, amp.clear_fault, amp.monitor_current):
        with pytest.raises(ValueError):
            call()
    assert amp.faulted() is False
    amp.disable()
    assert b.calls == [("write_volts", (1, 0.0), {"update": True})]


# --- PWM H-bridge ----------------------------------------------------------------------------
def _hbridge(boards: Boards | None = None, *, wired: bool = True) -> tuple[HBridgeAmp, Boards]:
    b = boards or Boards()
    if wired:
        cfg = HBridgeConfig(supply_v=24.0, direction_line="dir", brake_line="brk", fault_line="flt",
                            reset_line="rst", enable_line="en", monitor_channel=6, monitor_v_per_a=0.25)
    else:
        cfg = HBridgeConfig(supply_v=24.0, direction_line="dir")
    return HBridgeAmp(cfg, b, b if wired else None), b


def test_duty_for_current_feeds_the_back_emf_forward_and_clamps() -> None:
    # V = R·i + Ke·ω as a fraction of the supply: (2·3 + 0.5·4) / 24 = 1/3
    assert duty_for_current(3.0, 2.0, 0.5, 4.0, 24.0) == pytest.approx(1.0 / 3.0)
    assert duty_for_current(-3.0, 2.0, 0.5, -4.0, 24.0) == pytest.approx(-1.0 / 3.0)
    assert duty_for_current(20.0, 2.0, 0.5, 4.0, 24.0) == 1.0  # 42/24
    assert duty_for_current(-20.0, 2.0, 0.5, 4.0, 24.0) == -1.0  # −38/24


def test_hbridge_set_duty_releases_the_brake_then_sets_the_pwm() -> None:
    hb, b = _hbridge()
    assert hb.duty == 0.0
    hb.set_duty(-0.25)
    assert b.calls == [("set_line", ("brk", False), {}), ("set_pwm", (-0.25,), {"direction_line": "dir"})]
    assert hb.duty == -0.25
    b.calls.clear()
    hb.set_duty(1.0)  # the ends of the range are allowed
    hb.set_duty(-1.0)
    assert [c[1][0] for c in b.calls if c[0] == "set_pwm"] == [1.0, -1.0]


def test_hbridge_set_duty_refuses_outside_minus_one_to_one_and_nan() -> None:
    hb, b = _hbridge()
    for bad in (1.5, -1.0000001, math.nan):
        with pytest.raises(ValueError, match=r"^H-bridge duty .* is outside \[-1, 1\]$"):
            hb.set_duty(bad)
    with pytest.raises(ValueError, match=r"^H-bridge duty 1\.5 is outside \[-1, 1\]$"):
        hb.set_duty(1.5)
    assert b.calls == [] and hb.duty == 0.0


def test_hbridge_set_voltage_is_a_fraction_of_the_supply_clamped() -> None:
    hb, b = _hbridge()
    # the doc's worked examples: −6 V → −0.25, 12 V → 0.5, 30 V → 1.0, 0.3 V → 0.0125
    assert [hb.set_voltage(v) for v in (-6.0, 12.0, 30.0, 0.3, -30.0)] == pytest.approx(
        [-0.25, 0.5, 1.0, 0.0125, -1.0])
    assert [c[1][0] for c in b.calls if c[0] == "set_pwm"] == pytest.approx([-0.25, 0.5, 1.0, 0.0125, -1.0])
    assert hb.duty == -1.0


def test_hbridge_brake_coast_enable_and_disable_lines_in_order() -> None:
    hb, b = _hbridge()
    hb.set_duty(0.5)
    b.calls.clear()
    hb.brake()  # duty 0, then the brake line high
    assert b.calls == [("set_pwm", (0.0,), {"direction_line": "dir"}), ("set_line", ("brk", True), {})]
    assert hb.duty == 0.0
    hb.set_duty(0.5)
    b.calls.clear()
    hb.coast()
    assert b.calls == [("set_pwm", (0.0,), {"direction_line": "dir"}), ("set_line", ("brk", False), {})]
    assert hb.duty == 0.0
    b.calls.clear()
    hb.enable()
    hb.enable(False)
    assert b.calls == [("set_line", ("en", True), {}), ("set_line", ("en", False), {})]
    hb.set_duty(0.5)
    b.calls.clear()
    hb.disable()  # coast, then the enable low
    assert b.calls == [("set_pwm", (0.0,), {"direction_line": "dir"}), ("set_line", ("brk", False), {}),
                       ("set_line", ("en", False), {})]
    assert hb.duty == 0.0


def test_hbridge_fault_line_reset_pulse_and_current_monitor() -> None:
    hb, b = _hbridge(Boards(lines={"flt": True}, volts={6: -0.5}))
    assert hb.faulted() is True
    with pytest.raises(AmplifierFault, match=r"^H-bridge fault line asserted \(over-current or thermal\); "
                                             r"clear_fault\(\) after cooling$"):
        hb.check()
    b.lines["flt"] = False
    assert hb.faulted() is False
    hb.check()
    b.calls.clear()
    hb.clear_fault()
    assert b.calls == [("set_line", ("rst", True), {}), ("set_line", ("rst", False), {})]
    b.calls.clear()
    assert hb.monitor_current() == pytest.approx(-2.0)  # −0.5 V / 0.25 V/A
    assert b.calls == [("read_volts", (6,), {})]


def test_hbridge_without_brake_enable_fault_reset_or_monitor() -> None:
    hb, b = _hbridge(wired=False)
    hb.set_duty(0.5)
    assert b.calls == [("set_pwm", (0.5,), {"direction_line": "dir"})]  # no brake line to release
    b.calls.clear()
    hb.coast()
    hb.enable()
    hb.disable()
    assert b.calls == [("set_pwm", (0.0,), {"direction_line": "dir"})] * 2
    assert hb.faulted() is False
    hb.check()
    b.calls.clear()
    with pytest.raises(ValueError, match=r"^this H-bridge has no brake line wired$"):
        hb.brake()
    assert b.calls == [("set_pwm", (0.0,), {"direction_line": "dir"})]  # the PWM is off all the same
    with pytest.raises(ValueError, match=r"^this H-bridge has no fault-reset line wired$"):
        hb.clear_fault()
    with pytest.raises(ValueError, match=r"^this H-bridge's current monitor is not wired$"):
        hb.monitor_current()
    # an ADC but no channel named, and the default monitor scaling of 1 V/A
    cfg = HBridgeConfig(supply_v=24.0, direction_line="dir", monitor_channel=3)
    assert HBridgeAmp(cfg, b, Boards(volts={3: 0.75})).monitor_current() == 0.75
    with pytest.raises(ValueError, match="current monitor is not wired"):
        HBridgeAmp(HBridgeConfig(supply_v=24.0, direction_line="dir"), b, b).monitor_current()
