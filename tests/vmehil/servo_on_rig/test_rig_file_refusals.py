"""A bad rig file is refused with a typed error naming the file and the key, before anything
is built or moved."""

from __future__ import annotations

import math
import re

import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError
from servo.rig import load_rig
from vmehil.rig_setup.system import build_emulated_rig

PRESET = resolve_rig("jpl-arm").read_text()


def _rig(tmp_path, text: str):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    return p


def _swap_first(pattern: str, replacement: str) -> str:
    new, n = re.subn(pattern, replacement, PRESET, count=1, flags=re.M)
    assert n == 1, pattern
    return new


@pytest.mark.parametrize(("edit", "key", "expected"), [
    # j2's pot on j1's ADC pin: today j1 would run 79.5° off before the following-error stop
    ((r'^pot = "adc0:1"', 'pot = "adc0:0"'), "joint[1].wiring.pot", "already carries j1.pot"),
    ((r'^pot = "adc0:0"', 'pot = "dac0:0"'), "joint[0].wiring.pot", "a pin of a adc board"),
    ((r'^pot = "adc0:0"', 'pot = "adc0:16"'), "joint[0].wiring.pot", "adc channel 0..15"),
    ((r'^pot = "adc0:0"', 'pot = "adc9:0"'), "joint[0].wiring.pot", "no board named 'adc9'"),
    ((r'^name = "adc1"', 'name = "adc0"'), "crate.board[1].name", "a board name not used before"),
    ((r'^slot = 3', 'slot = 2'), "crate.board[1].slot", "a free slot"),
    # a holding brake's line is a PIO output, free (issue #29)
    ((r'^holding_brake = "pio1:PA0"', 'holding_brake = "dac0:6"'), "joint[1].wiring.holding_brake",
     "a pin of a pio board"),
    ((r'^holding_brake = "pio1:PA1"', 'holding_brake = "pio1:PA0"'), "joint[2].wiring.holding_brake",
     "already carries j2.holding_brake"),
])
def test_a_miswired_rig_is_refused_naming_file_and_key(tmp_path, edit, key, expected) -> None:
    path = _rig(tmp_path, _swap_first(*edit))
    with pytest.raises(ConfigError) as e:
        load_rig(path)
    assert str(path) in str(e.value) and f"'{key}'" in str(e.value) and expected in str(e.value)


@pytest.mark.parametrize("value", ["inf", "-inf", "nan"])
def test_non_finite_physics_is_refused(tmp_path, value) -> None:
    text = _swap_first(r"^kt_nm_per_a = [0-9.e+-]+", f"kt_nm_per_a = {value}")
    with pytest.raises(ConfigError, match="a finite number"):
        build_emulated_rig(load_rig(_rig(tmp_path, text)))
    assert not math.isfinite(float(value))


def test_overlapping_board_windows_are_refused_when_the_crate_is_built(tmp_path) -> None:
    text = _swap_first(r"^base = 0x6100", "base = 0x6010")
    with pytest.raises(ConfigError, match=r"crate\.board\[1\]\.base.*a free window"):
        build_emulated_rig(load_rig(_rig(tmp_path, text)))


def test_a_rig_file_that_is_not_utf8_is_refused_naming_the_file(tmp_path) -> None:
    """Found by tests/fuzz/test_rig_file.py: a stray byte used to end in UnicodeDecodeError."""
    path = tmp_path / "bad.toml"
    path.write_bytes(b"\x80" + PRESET.encode())
    with pytest.raises(ConfigError, match="a UTF-8 text file") as e:
        load_rig(path)
    assert str(path) in str(e.value) and e.value.key == "" and "key" not in str(e.value)


def test_a_servo_sensor_that_is_not_wired_is_refused_naming_file_and_key(tmp_path) -> None:
    """Found by tests/fuzz/test_rig_file.py: this used to be a bare ValueError naming neither."""
    path = _rig(tmp_path, _swap_first(r'^tach = "adc0:8"\n', ""))
    with pytest.raises(ConfigError) as e:
        build_emulated_rig(load_rig(path))
    assert str(path) in str(e.value) and "'tach' is not wired" in str(e.value)
    assert e.value.key.endswith("servo.velocity"), e.value.key


def test_a_pwm_period_the_pio_cannot_take_is_refused_naming_file_and_key(tmp_path) -> None:
    """Found by tests/fuzz/test_rig_file.py: this used to be a bare PwmRangeError from the driver."""
    path = _rig(tmp_path, _swap_first(r"^pwm_period_s = 5\.0e-5", "pwm_period_s = 2066.0"))
    with pytest.raises(ConfigError) as e:
        build_emulated_rig(load_rig(path))
    assert str(path) in str(e.value) and "PWM timer" in str(e.value)
    assert e.value.key.endswith("servo.nominal.pwm_period_s"), e.value.key


def test_a_zero_planning_speed_limit_is_refused_naming_file_and_key(tmp_path) -> None:
    """Found by tests/fuzz/test_rig_file.py: this used to escape as a TrajectoryError naming neither."""
    from vmehil.rig_setup.session import build_loop

    path = _rig(tmp_path, _swap_first(r"^max_velocity_deg_s = 20\.0", "max_velocity_deg_s = 0.0"))
    system = build_emulated_rig(load_rig(path))
    try:
        with pytest.raises(ConfigError) as e:
            build_loop(system)
        assert str(path) in str(e.value) and e.value.key.endswith("servo.max_velocity_deg_s"), e.value.key
    finally:
        system.close()
