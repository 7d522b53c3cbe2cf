"""Rig-level calibration wiring: [rig.references] and [rig.loopback]."""

from __future__ import annotations

import pytest

from hal.config import ConfigError
from servo.rig import Pin, loopback_net, reference_net
from tests.support.bench_rig import RIG_TOML, write_rig


def test_references_and_loopback_are_parsed(tmp_path):
    rig = write_rig(tmp_path)
    assert rig.references == {Pin("adc1", 12): 5.0, Pin("adc1", 13): 0.0}
    assert rig.loopback == {Pin("dac0", 6): Pin("adc1", 14), Pin("dac0", 7): Pin("adc1", 15)}
    assert reference_net(Pin("adc1", 12)) == "ref.adc1.12"
    assert loopback_net(Pin("dac0", 6)) == "loop.dac0.6"


@pytest.mark.parametrize(
    ("old", "new", "message"),
    [
        ('"adc1:12" = 5.0', '"dac0:5" = 5.0', "adc pin"),
        ('"adc1:12" = 5.0', '"adc1:0" = 5.0', "j1.imon"),
        ('"dac0:6" = "adc1:14"', '"dac0:0" = "adc1:14"', "j1.amp_command"),
        ('"dac0:7" = "adc1:15"', '"dac0:7" = "adc1:14"', "already carries"),
        ('"dac0:6" = "adc1:14"', '"adc1:6" = "adc1:14"', "dac pin"),
        ('"adc1:12" = 5.0', '"adc1:12" = 50.0', "adc1:12"),
    ],
)
def test_bad_calibration_wiring_is_refused(tmp_path, old, new, message):
    assert old in RIG_TOML
    with pytest.raises(ConfigError, match=message):
        write_rig(tmp_path, RIG_TOML.replace(old, new))
