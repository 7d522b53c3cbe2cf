"""What the controller may know: the rig file's servo side (``[joint.servo.nominal]``), never
the plant's own parameters; and the plant reads only its own tables of the shared rig file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from emulators.plant import load_plant_params
from emulators.plant.params import JointParams as PlantJoint
from emulators.presets import preset_names, resolve_rig
from hal.config import ConfigError
from servo.nominal import NOMINAL_KEYS, required_keys, rig_nominal
from servo.rig import load_rig
from vmehil.analysis.rigparams import load_joint
from vmehil.rig_setup.session import build_loop, servo_settings
from vmehil.rig_setup.system import build_emulated_rig


def _variant(tmp_path: Path, name: str, *subs: tuple[str, str], rig: str = "jpl-arm") -> Path:
    """The preset with each ``old`` replaced by ``new`` (first occurrence)."""
    text = resolve_rig(rig).read_text()
    for old, new in subs:
        assert old in text, old
        text = text.replace(old, new, 1)
    p = tmp_path / f"{name}.toml"
    p.write_text(text)
    return p


def test_the_application_names_the_non_plant_tables_so_plant_typos_are_errors(tmp_path: Path) -> None:
    typo = _variant(tmp_path, "typo", ("\n[joint.friction]", "\n[joint.fricton]"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.fricton.*unknown key"):
        build_emulated_rig(typo)
    # [joint.calibration] (the pot procedure's travel) belongs to the calibration, not the plant
    travel = _variant(tmp_path, "travel", ("\n[joint.wiring]", "\n[joint.calibration]\n"
                                                              "pot_travel_deg = [-150.0, 150.0]\n[joint.wiring]"))
    build_emulated_rig(travel).close()


def _expected_from_plant(p: PlantJoint) -> dict[str, float]:
    """Today's plant figures the preset's nominal tables were generated from (the oracle)."""
    span_v = p.pot.v_high - p.pot.v_low
    linear = p.amplifier == "linear"
    return {
        "ratio": p.gear.ratio, "kt_nm_per_a": p.motor.kt_nm_per_a, "inertia_kg_m2": p.inertia_at_joint(),
        "current_limit_a": p.linear_amp.current_limit_a if linear else p.hbridge.current_limit_a,
        "monitor_v_per_a": p.linear_amp.monitor_v_per_a if linear else p.hbridge.monitor_v_per_a,
        "amp_gain_a_per_v": p.linear_amp.gain_a_per_v, "pot_v_per_rad": span_v / p.pot.span_rad,
        "pot_zero_v": p.pot.v_low + span_v * (0.5 - p.pot.center_rad / p.pot.span_rad),
        "tach_v_per_rad_s": p.tach.gradient_v_per_rad_s,
        "tach_dead_band_rad_s": p.tach.brush_drop_v / p.tach.gradient_v_per_rad_s,
        "encoder_counts_per_rev": 4.0 * p.encoder.lines_per_rev * p.gear.ratio,
        "supply_v": p.hbridge.supply_v, "resistance_ohm": p.motor.resistance_ohm,
        "ke_v_s_per_rad": p.motor.ke_v_s_per_rad, "pwm_period_s": 1.0 / p.hbridge.pwm_hz,
        "gravity_torque_nm": p.link.gravity_torque_nm, "gravity_phase_rad": p.link.gravity_phase_rad,
    }


@pytest.mark.parametrize("rig", preset_names())
def test_preset_nominal_values_equal_the_plants_so_default_runs_are_unchanged(rig: str) -> None:
    """The presets state the plant's values to the last bit: the default runs give the same
    numbers as when the controller read the plant (checked against the base commit: a 30 s
    jpl-arm run, every recorded array bit-identical)."""
    spec = load_rig(resolve_rig(rig))
    plant = load_plant_params(rig).joints
    for j, n, p in zip(spec.joints, rig_nominal(spec), plant, strict=True):
        want = _expected_from_plant(p)
        given = {k: getattr(n, k) for k in NOMINAL_KEYS if getattr(n, k) is not None}
        assert set(required_keys(j)) <= set(given), j.name
        assert given == {k: want[k] for k in given}, j.name


def test_a_perturbed_plant_leaves_the_controllers_gains_and_scaling_unchanged(tmp_path: Path) -> None:
    """Joint 1's link inertia and Kt ×1.3 in the plant tables: the plant changes, the
    controller (normalizing chain, torque limit, sensor scaling) does not — it knows only its
    nominal values; the tuning analysis says by how much the normalized plant is off."""
    perturbed = _variant(tmp_path, "perturbed", ("inertia_kg_m2 = 2.0 ", "inertia_kg_m2 = 2.6 "),
                         ("kt_nm_per_a = 0.028 ", "kt_nm_per_a = 0.0364 "))
    base, other = build_emulated_rig(None), build_emulated_rig(perturbed)
    try:
        assert other.params[0].link.inertia_kg_m2 == pytest.approx(1.3 * base.params[0].link.inertia_kg_m2)
        assert other.params[0].motor.kt_nm_per_a == pytest.approx(1.3 * base.params[0].motor.kt_nm_per_a)
        assert other.io.scaling == base.io.scaling
        a, b = build_loop(base, n_ticks=1), build_loop(other, n_ticks=1)
        ca, cb = a.controller.active.chain, b.controller.active.chain
        for name in ("j_eff", "ratio", "kt", "amp_gain"):
            assert np.array_equal(getattr(cb, name), getattr(ca, name)), name
        assert servo_settings(other.rig).torque_limit_nm == servo_settings(base.rig).torque_limit_nm
    finally:
        base.close()
        other.close()
    jp = load_joint(perturbed, 1)
    j_nom = 3.0000000000000004
    r = j_nom / jp.inertia_kg_m2 * 1.3  # the controller's J over the plant's, times the plant's Kt over the nominal
    assert any(f"{r:.4g}/s²" in note for note in jp.notes), jp.notes
    assert not any("/s²" in note for note in load_joint(None, 1).notes)


def test_a_missing_or_unknown_nominal_key_names_the_key(tmp_path: Path) -> None:
    missing = _variant(tmp_path, "missing", ("kt_nm_per_a = 0.028\namp_gain_a_per_v", "amp_gain_a_per_v"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.servo\.nominal\.kt_nm_per_a.*missing"):
        build_emulated_rig(missing)
    unknown = _variant(tmp_path, "unknown", ("kt_nm_per_a = 0.028\n", "kt_nm_per_a = 0.028\nkt = 0.028\n"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.servo\.nominal\.kt.*unknown key"):
        rig_nominal(load_rig(unknown))
    no_table = _variant(tmp_path, "no_table", ("\n[joint.servo.nominal]", "\n[joint.servo.datasheet]"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.servo\.nominal.*datasheet values"):
        rig_nominal(load_rig(no_table))
    negative = _variant(tmp_path, "negative", ("ratio = 100.0\n", "ratio = -100.0\n"))
    with pytest.raises(ConfigError, match=r"joint\[0\]\.servo\.nominal\.ratio.*> 0"):
        rig_nominal(load_rig(negative))


def test_only_what_the_joint_uses_is_required() -> None:
    """The hand (H-bridge, no tach) gives no amplifier gain and no tach gradient; its chain's
    volts stage is the neutral 1 A/V."""
    spec = load_rig(resolve_rig("jpl-arm"))
    hand = spec.joints[6]
    assert hand.amplifier == "hbridge" and "tach" not in hand.wiring
    assert "amp_gain_a_per_v" not in required_keys(hand) and "tach_v_per_rad_s" not in required_keys(hand)
    assert {"supply_v", "resistance_ohm", "ke_v_s_per_rad", "pwm_period_s"} <= set(required_keys(hand))
    assert "supply_v" not in required_keys(spec.joints[0])
    n = rig_nominal(spec)[6]
    assert n.amp_gain_a_per_v is None and n.chain_amp_gain_a_per_v == 1.0
    assert n.scaling().pwm_period_s == 5.0e-5 and n.torque_limit_nm == pytest.approx(2.0 * 0.01 * 50.0)
