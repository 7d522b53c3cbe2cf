"""Plant sections of rig files: presets, templates, and errors naming file and key."""

from __future__ import annotations

import numpy as np
import pytest

from emulators.plant import AMP_HBRIDGE, Plant, load_plant, load_plant_params
from emulators.plant.params import FrictionParams, JointParams
from emulators.presets import resolve_rig
from hal.config import ConfigError, load_toml
from hal.units import oz_in_to_nm


def test_jpl_arm_joint1_carries_the_papers_numbers():
    params = load_plant_params("jpl-arm")
    assert [j.name for j in params.joints] == ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]
    assert params.joints[6].amplifier == AMP_HBRIDGE
    assert all(j.amplifier == "linear" for j in params.joints[:6])
    j1 = params.joints[0]
    assert j1.gear.ratio == 100.0
    assert j1.inertia_at_joint() == pytest.approx(3.0, rel=1e-9)
    assert j1.motor.rotor_inertia_kg_m2 * 100**2 == pytest.approx(1.0)
    assert 5.0 <= j1.friction.breakout_nm / oz_in_to_nm(1.0) <= 9.0
    assert j1.breakout_at_output_nm() == pytest.approx(oz_in_to_nm(650.0), rel=0.01)
    assert j1.motor.peak_torque_nm == pytest.approx(oz_in_to_nm(120.0), rel=0.01)
    # ≈ 1.5 A of drive current at the breakout
    assert j1.friction.breakout_nm / j1.motor.kt_nm_per_a == pytest.approx(1.6, abs=0.15)
    assert j1.tach.brush_drop_v / j1.tach.gradient_v_per_rad_s == pytest.approx(0.12)
    assert params.rate_hz == 4000.0


def test_melmalec_has_sixteen_motors_in_five_three_axis_units_plus_one():
    p = load_plant("melmalec-16")
    assert p.n_joints == 16
    units = {n.split("_")[0] for n in p.names if n != "crawler"}
    assert units == {"leg1", "leg2", "leg3", "leg4", "arm"}
    assert all(sum(n.startswith(u + "_") for n in p.names) == 3 for u in units)
    elbow = p.params.joints[p.index_of("arm_elbow")]
    assert elbow.link.gravity_torque_nm == 5.0  # joint keys override the template
    assert elbow.motor.kt_nm_per_a == 0.03  # the rest comes from the template
    c = p.idle_command()
    c.amp_enable[:] = True
    c.amp_command_v[:] = 0.2
    s = p.step_period(c, 0.008)
    assert s.pot_v.shape == (16,) and len(s.encoder) == 16


def test_from_config_equals_loading_the_preset():
    cfg = load_toml(resolve_rig("jpl-arm"))
    a = Plant.from_config(cfg, seed=1)
    b = load_plant("jpl-arm", seed=1)
    cmd = a.idle_command()
    assert np.array_equal(a.step_period(cmd, 0.008).pot_v, b.step_period(cmd, 0.008).pot_v)


def _rig(tmp_path, text: str):
    f = tmp_path / "rig.toml"
    f.write_text(text)
    return f


def test_unknown_key_names_file_and_key(tmp_path):
    f = _rig(tmp_path, '[[joint]]\nname = "a"\n[joint.friction]\nbreakout = 0.1\n')
    with pytest.raises(ConfigError) as e:
        load_plant_params(f)
    assert str(f) in str(e.value) and "joint[0].friction.breakout" in str(e.value)


def test_wrong_type_names_the_key(tmp_path):
    f = _rig(tmp_path, '[[joint]]\nname = "a"\n[joint.motor]\nresistance_ohm = "low"\n')
    with pytest.raises(ConfigError, match=r"joint\[0\]\.motor\.resistance_ohm.*a number"):
        load_plant_params(f)


def test_meaningless_values_and_bad_choices_are_rejected(tmp_path):
    f = _rig(tmp_path, '[[joint]]\nname = "a"\n[joint.friction]\nripple_fraction = 1.5\n')
    with pytest.raises(ConfigError, match="ripple_fraction"):
        load_plant_params(f)
    f = _rig(tmp_path, '[[joint]]\nname = "a"\namplifier = "pwm"\n')
    with pytest.raises(ConfigError, match="amplifier.*linear, hbridge"):
        load_plant_params(f)
    f = _rig(tmp_path, '[[joint]]\nname = "a"\ntemplate = "nope"\n')
    with pytest.raises(ConfigError, match="template"):
        load_plant_params(f)
    f = _rig(tmp_path, '[plant]\nrate_hz = 4000.0\n')
    with pytest.raises(ConfigError, match="joint"):
        load_plant_params(f)
    f = _rig(tmp_path, '[plant]\nrate = 4000.0\n[[joint]]\nname = "a"\n')
    with pytest.raises(ConfigError, match=r"plant\.rate"):
        load_plant_params(f)


def test_missing_keys_take_the_documented_defaults(tmp_path):
    f = _rig(tmp_path, '[plant]\nrate_hz = 8000.0\n[[joint]]\nname = "a"\n')
    params = load_plant_params(f)
    assert params.rate_hz == 8000.0
    assert params.joints[0].friction == FrictionParams()
    assert params.joints[0] == JointParams(name="a")
    assert Plant(params).rate_hz == 8000.0


def test_unknown_preset_names_the_presets():
    with pytest.raises(FileNotFoundError, match="jpl-arm.*melmalec-16|melmalec-16.*jpl-arm"):
        load_plant_params("no-such-rig")


def test_other_readers_tables_are_skipped_only_when_the_caller_names_them(tmp_path):
    """The plant does not know the rig file's other readers: a caller that knows them passes their
    [[joint]] keys; without them the plant leaves keys it does not own unchecked."""
    text = '[[joint]]\nname = "a"\n[joint.ctl]\nanything = 1\n[joint.friction]\nbreakout_nm = 0.1\n'
    f = _rig(tmp_path, text)
    assert load_plant_params(f).joints[0].friction.breakout_nm == 0.1
    assert load_plant_params(f, foreign_keys=("ctl",)).joints[0].friction.breakout_nm == 0.1
    with pytest.raises(ConfigError, match=r"joint\[0\]\.ctl.*unknown key"):
        load_plant_params(f, foreign_keys=("wiring",))
    typo = _rig(tmp_path, '[[joint]]\nname = "a"\n[joint.fricton]\nbreakout_nm = 0.1\n')
    with pytest.raises(ConfigError, match=r"joint\[0\]\.fricton"):
        Plant.from_config(load_toml(typo), foreign_keys=("ctl",))
