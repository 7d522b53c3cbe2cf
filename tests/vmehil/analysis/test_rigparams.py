"""Joint parameters for the analysis come from the real rig: session gain/switch-off resolution,
the control law's switch-off gain, the plant parameters and the ADC resolution."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from emulators.plant import load_plant_params
from emulators.presets import resolve_rig
from hal.adc_dac.conversions import N_CODES
from servo.control.errors import GainError
from vmehil.analysis.rigparams import load_joint, with_gains
from vmehil.rig_setup.session import build_loop, servo_settings
from vmehil.rig_setup.system import build_emulated_rig


def _variant(tmp_path: Path, *subs: tuple[str, str]) -> Path:
    text = resolve_rig("jpl-arm").read_text()
    for old, new in subs:
        assert old in text
        text = text.replace(old, new, 1)
    p = tmp_path / "rig.toml"
    p.write_text(text)
    return p


def test_joint_1_figures_come_from_the_plant_parameters() -> None:
    jp = load_joint(None, 1)
    p = load_plant_params("jpl-arm").joints[0]
    n = p.gear.ratio
    assert jp.inertia_kg_m2 == pytest.approx(p.inertia_at_joint())
    assert jp.coulomb_nm == pytest.approx(n * p.friction.coulomb_nm)
    assert jp.breakout_nm == pytest.approx(n * p.friction.breakout_nm * (1 + p.friction.ripple_fraction))
    assert jp.cfg.viscous_damping == pytest.approx(n * n * p.friction.viscous_nm_s_per_rad / p.inertia_at_joint())
    assert jp.tach_deadband_rad_s == pytest.approx(p.tach.brush_drop_v / p.tach.gradient_v_per_rad_s)
    assert jp.cfg.velocity_filter_hz == pytest.approx(1 / (2 * math.pi * p.tach.filter_time_constant_s))
    # one 12-bit ADC step (±10 V) over the pot's V/rad
    assert jp.position_quantum_rad == pytest.approx((20.0 / N_CODES) / ((p.pot.v_high - p.pot.v_low) / p.pot.span_rad))
    assert jp.cfg.amplifier_bandwidth_hz == p.linear_amp.bandwidth_hz
    assert jp.cfg.delay_s == pytest.approx(0.001) and jp.cfg.sample_period_s == pytest.approx(0.008)
    assert jp.cfg.velocity_source == "tach" and jp.position_source == "pot"
    assert jp.notes == []  # every figure is in the rig file


def test_gains_switch_off_gain_and_torque_limit_match_the_session_and_the_law() -> None:
    system = build_emulated_rig(None)
    st = servo_settings(system.rig)
    loop = build_loop(system, n_ticks=1)
    for j in (1, 4):
        jp = load_joint(None, j)
        assert jp.cfg.gains == st.gains.joint(j - 1)
        assert jp.switch_off_kp == pytest.approx(float(loop.law.kp_off()[j - 1]))
        assert jp.torque_limit_nm == pytest.approx(st.torque_limit_nm[j - 1])
        inertia = system.params[j - 1].inertia_at_joint()
        assert jp.accel_limit_rad_s2 == pytest.approx(st.torque_limit_nm[j - 1] / inertia)
    system.close()


def test_joint_servo_overrides_and_an_explicit_boost_are_read(tmp_path: Path) -> None:
    rig = _variant(tmp_path, ('velocity = "tach"\n', 'velocity = "tach"\ngains = { kp = 150, kv = 60 }\n'
                                                      'switch_off = { kp_boost = 3.0 }\n'),
                   ("switch_off = { enabled = true }", "switch_off = { enabled = true, kp_boost = 2.0 }"))
    jp = load_joint(rig, 1)
    assert jp.cfg.gains.as_dict() == {"kp": 150.0, "kpi": 5000.0, "kv": 60.0, "kvi": 1000.0}
    assert jp.switch_off_kp == pytest.approx(450.0)  # PidLaw.kp_off: Kp · boost
    j2 = load_joint(rig, 2)
    assert j2.cfg.gains.kp == 100.0 and j2.switch_off_kp == pytest.approx(200.0)  # [servo] defaults
    # --gains overrides this joint; the boost follows the law
    assert load_joint(rig, 1, gains="kp=200").switch_off_kp == pytest.approx(600.0)
    assert with_gains(jp, jp.cfg.gains.__class__(kp=120, kpi=5000, kv=50, kvi=1000)).switch_off_kp == pytest.approx(360)


def test_auto_boost_is_kp_plus_kvi_for_overridden_gains() -> None:
    jp = load_joint(None, 1, gains={"kp": 80.0, "kvi": 1400.0})
    assert jp.switch_off_kp == pytest.approx(1480.0)
    assert jp.gain_overrides == {"kp": 80.0, "kvi": 1400.0}


def test_encoder_velocity_joint_and_missing_keys_are_noted(tmp_path: Path) -> None:
    jp2 = load_joint(None, 2)
    assert jp2.cfg.velocity_source == "encoder" and jp2.tach_deadband_rad_s is None
    assert jp2.cfg.velocity_filter_hz is None
    assert any("bandwidth_hz" in n for n in jp2.notes)  # j2 has no bandwidth_hz: the plant default, noted
    assert any("gravity" in n for n in jp2.notes)


@pytest.mark.parametrize("gains", ["kp=-1", "kv=nan", "kvi=inf", "kq=2"])
def test_bad_gains_raise_gain_errors(gains: str) -> None:
    with pytest.raises(GainError):
        load_joint(None, 1, gains=gains)


def test_joint_numbers_are_checked() -> None:
    with pytest.raises(ValueError, match="1..7"):
        load_joint(None, 9)
    with pytest.raises(ValueError, match="numbered from 1"):
        load_joint(None, 0)


def test_computation_delay_and_rate_follow_the_rig(tmp_path: Path) -> None:
    rig = _variant(tmp_path, ("computation_delay_s = 0.001", "computation_delay_s = 0.008"))
    jp = load_joint(rig, 1)
    assert jp.cfg.delay_fraction == pytest.approx(1.0)
    assert np.isfinite(jp.accel_limit_rad_s2)
