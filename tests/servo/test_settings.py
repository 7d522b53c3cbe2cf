"""servo.settings: the rig file's servo sections parsed once into typed frozen settings; every gain
set from the rig file goes through the gain guard, as one from the command line does (issue #30
item 3); an override is applied in one place with one check."""

from __future__ import annotations

import dataclasses
import pickle
from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError
from servo.control.gains import Gains
from servo.gain_guard import GainRejected
from servo.rig import load_rig
from servo.settings import ServoSettings, servo_settings

PAPER = 'gains = { kp = 100.0, kpi = 5000.0, kv = 50.0, kvi = 1000.0 }   # paper\'s gain set'


def _rig_with(tmp_path: Path, old: str, new: str) -> Path:
    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "rig.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


def test_the_jpl_arm_settings_are_the_papers_gains_per_joint_and_frozen() -> None:
    st = servo_settings(load_rig(resolve_rig("jpl-arm")))
    assert st.n == 7 and st.objects == ("pid", "torque_limit")
    assert st.gains.joint(0) == Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    assert st.gains.joint(6) == Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    assert st.max_velocity_rad_s[0] == pytest.approx(np.radians(20.0))  # [servo] max_velocity_deg_s = 20
    assert st.period_s == pytest.approx(0.008)
    with pytest.raises(dataclasses.FrozenInstanceError):
        st.objects = ("pid",)  # type: ignore[misc]
    assert pickle.loads(pickle.dumps(st)).gains == st.gains  # a sweep point carries them to a worker


def test_rig_file_gains_beyond_the_guards_limit_are_refused_naming_the_file(tmp_path: Path) -> None:
    rig = load_rig(_rig_with(tmp_path, PAPER, "gains = { kp = 1e30, kpi = 5000.0, kv = 50.0, kvi = 1000.0 }"))
    with pytest.raises(ConfigError, match="limited to 100000") as e:
        servo_settings(rig)
    assert e.value.key == "servo.gains" and str(tmp_path / "rig.toml") in str(e.value)


def test_rig_file_gains_with_an_unstable_sampled_loop_are_refused(tmp_path: Path) -> None:
    # the case: refused on the command line (pole radius 2.21), ran from a rig file
    rig = load_rig(_rig_with(tmp_path, PAPER, "gains = { kp = 100000, kpi = 5000.0, kv = 0, kvi = 1000.0 }"))
    with pytest.raises(ConfigError, match=r"unstable \(pole radius 2\.21"):
        servo_settings(rig)


def test_one_joints_unstable_gains_are_refused_naming_that_joints_table(tmp_path: Path) -> None:
    path = _rig_with(tmp_path, "\n[joint.servo]\n", "\n[joint.servo]\ngains = { kv = 0, kp = 100000 }\n")
    with pytest.raises(ConfigError, match="joint j1: the sampled loop would be unstable") as e:
        servo_settings(load_rig(path))
    assert e.value.key == "joint[0].servo.gains"


def test_an_override_is_checked_once_and_leaves_the_rigs_settings_alone() -> None:
    st = servo_settings(load_rig(resolve_rig("jpl-arm")))
    with pytest.raises(GainRejected, match="limited to 100000"):
        st.overridden({"kp": 1e30})
    with pytest.raises(GainRejected, match=r"pole radius 2\.21"):
        st.overridden({"kp": 100000.0, "kv": 0.0})
    new = st.overridden({"kp": 120.0}, switch_off=False)
    assert isinstance(new, ServoSettings)
    assert new.gains.joint(3) == Gains(kp=120.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    assert not new.switch_off.enabled.any() and st.switch_off.enabled.all()
    assert st.gains.joint(3).kp == 100.0  # the rig's settings are unchanged


def test_require_homing_is_a_rig_setting_off_by_default_and_typed(tmp_path: Path) -> None:
    assert servo_settings(load_rig(resolve_rig("jpl-arm"))).require_homing is False
    on = _rig_with(tmp_path, "max_velocity_deg_s = 20.0", "max_velocity_deg_s = 20.0\nrequire_homing = true")
    assert servo_settings(load_rig(on)).require_homing is True
    bad = _rig_with(tmp_path, "max_velocity_deg_s = 20.0", 'max_velocity_deg_s = 20.0\nrequire_homing = "yes"')
    with pytest.raises(ConfigError) as e:
        servo_settings(load_rig(bad))
    assert e.value.key == "servo.require_homing"
