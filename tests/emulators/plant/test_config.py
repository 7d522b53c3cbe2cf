"""Plant sections of rig files: presets, templates, and errors naming file and key."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from emulators.plant import AMP_HBRIDGE, Plant, PlantParams, load_plant, load_plant_params
from emulators.plant.params import FrictionParams, JointParams
from emulators.presets import resolve_rig
from hal.config import ConfigError, load_toml
from hal.si import oz_in_to_nm


def test_jpl_arm_has_six_linear_joints_and_an_h_bridge_hand():
    params = load_plant_params("jpl-arm")
    assert [j.name for j in params.joints] == ["j1", "j2", "j3", "j4", "j5", "j6", "hand"]
    assert params.joints[6].amplifier == AMP_HBRIDGE
    assert all(j.amplifier == "linear" for j in params.joints[:6])


def _drive(plant: Plant, current_a: float, seconds: float, t: float = 0.008):
    jp = plant.params.joints[0]
    cmd = plant.idle_command()
    cmd.amp_enable[0] = True
    cmd.amp_command_v[0] = current_a / jp.linear_amp.gain_a_per_v
    s = None
    for _ in range(round(seconds / t)):
        s = plant.step_period(cmd, t)
    return s


def test_jpl_arm_joint1_behaves_as_the_papers_numbers_say():
    """Measured on the plant, not read back from the preset: the joint's inertia from its
    acceleration under a known torque (the paper's T_F/(J·Kp) ≈ ¾° needs J ≈ 3 kg·m²), and the
    drive current at which joint 1 breaks away (the paper: 6 oz-in ≈ 1.5 A)."""
    j1 = load_plant_params("jpl-arm").joints[0]
    n, kt = j1.gear.ratio, j1.motor.kt_nm_per_a
    # no friction: the joint accelerates as N·Kt·i / J from rest
    free = replace(j1, friction=FrictionParams(breakout_nm=0.0, coulomb_nm=0.0, viscous_nm_s_per_rad=0.0,
                                               ripple_fraction=0.0))
    plant = Plant(PlantParams(joints=[free]), seed=0)
    current, seconds = 2.0, 0.4
    theta0 = float(_drive(plant, 0.0, 0.008).truth["theta_joint"][0])  # at rest: no torque, no gravity
    s = _drive(plant, current, seconds)
    theta = float(s.truth["theta_joint"][0]) - theta0
    j_measured = n * kt * current * seconds**2 / (2 * theta)
    assert j_measured == pytest.approx(3.0, rel=0.03)
    # breakout: ramp the current at θm = 0 (ripple phase 0: the local breakout is T_s) until it moves
    moved_at = None
    plant = Plant(PlantParams(joints=[j1]), seed=0)
    for i_a in np.arange(1.0, 2.5, 0.01):
        s = _drive(plant, float(i_a), 0.008)
        if s.truth["theta_motor"][0] != 0.0:
            moved_at = float(i_a)
            break
    assert moved_at is not None and moved_at == pytest.approx(1.6, abs=0.15)
    assert 5.0 <= moved_at * kt / oz_in_to_nm(1.0) <= 9.0  # the paper's input breakout, oz-in


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
