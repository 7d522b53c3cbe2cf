"""Named controllers per joint (servo.named_controllers): the rig file's [[joint.controller]]
tables, the rig's default, the gain guard at parse time and at a switch (the law's bumpless
switch itself: tests/servo/control/test_switch_joint.py)."""

from __future__ import annotations

import numpy as np
import pytest

from hal.config import ConfigError
from servo.control.errors import ControlError
from servo.control.gains import Gains
from servo.control.law import PidLaw, SwitchOffConfig
from servo.gain_guard import GainRejected
from servo.named_controllers import use_controller
from servo.rig import load_rig
from servo.settings import servo_settings
from tests.support.rig_variants import STIFF, rig_with


def test_each_joint_has_its_default_then_the_rigs_named_controllers(tmp_path):
    s = servo_settings(load_rig(rig_with(tmp_path, STIFF)))
    c = s.controllers
    assert c is not None and c.any_named
    assert c.names(0) == ["default"] and c.names(1) == ["default", "stiff", "filtered", "tight"]
    assert c.start == (0,) * 7
    stiff = c.per_joint[1][1]
    assert stiff.gains == Gains(kp=200.0, kpi=10000.0, kv=60.0, kvi=2000.0)
    filt = c.per_joint[1][2]
    assert filt.gains == Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)  # the joint's own, as not given
    assert filt.filter_hz == 5.0
    assert s.velocity_filter_hz == ()  # nothing selects the filter by default


def test_the_rigs_default_controller_is_the_one_the_joint_starts_with(tmp_path):
    s = servo_settings(load_rig(rig_with(tmp_path, STIFF, servo_extra='controller = "filtered"')))
    assert s.controllers is not None and s.controllers.start[1] == 2
    assert s.filter_hz[1] == 5.0 and np.isnan(s.filter_hz[0])


def test_a_named_controller_the_guard_refuses_names_its_key(tmp_path):
    bad = '[[joint.controller]]\nname = "hot"\n[joint.controller.pid]\nkp = 5e4\n'
    with pytest.raises(ConfigError, match=r"joint\[1\]\.controller\[0\]\.pid.*unstable"):
        servo_settings(load_rig(rig_with(tmp_path, bad)))


def test_an_unknown_default_or_a_repeated_name_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="controller.*one of default, stiff, filtered, tight"):
        servo_settings(load_rig(rig_with(tmp_path, STIFF, servo_extra='controller = "nope"')))
    twice = '[[joint.controller]]\nname = "default"\n'
    with pytest.raises(ConfigError, match="not used before"):
        servo_settings(load_rig(rig_with(tmp_path, twice)))


def test_a_velocity_filter_of_the_joint_is_parsed_once(tmp_path):
    s = servo_settings(load_rig(rig_with(tmp_path, "", servo_extra="velocity_filter = { cutoff_hz = 8.0 }")))
    assert s.velocity_filter_hz[1] == 8.0 and np.isnan(s.velocity_filter_hz[0])
    with pytest.raises(ConfigError, match="cutoff_hz"):
        servo_settings(load_rig(rig_with(tmp_path, "", servo_extra="velocity_filter = { cutoff_hz = 0.0 }")))


def test_a_switch_the_guard_refuses_changes_nothing():
    law = PidLaw(2, 0.008, Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0), SwitchOffConfig.disabled(2))
    from servo.named_controllers import ControllerChoices, NamedController

    paper = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    hot = NamedController("hot", Gains(kp=5e4, kpi=5000.0, kv=50.0, kvi=1000.0))
    choices = ControllerChoices(((NamedController("default", paper), hot),) * 2, (0, 0))
    active = [0, 0]
    with pytest.raises(GainRejected, match="unstable"):
        use_controller(law, choices, active, "hot", [0, 1], 0.008, 0.125)
    with pytest.raises(ControlError, match="no controller 'cold'"):
        use_controller(law, choices, active, "cold", [1], 0.008, 0.125)
    assert active == [0, 0] and law._pending_switch == {}
