"""A bad calibration file is refused naming the file, the table and the key — never applied.
The fuzz harness (tests/fuzz/test_calibration_file.py) mangles a valid file at random."""

from __future__ import annotations

import re

import pytest

from tests.support.calib_bench import sample_store, write_rig
from vmehil.calibration.store import (
    CalibrationFileError,
    load_store,
)


@pytest.fixture
def valid(tmp_path):
    rig = write_rig(tmp_path)
    path = sample_store(rig).save(tmp_path / "cal.toml")
    return rig, path


@pytest.mark.parametrize(("pattern", "replacement", "expected"), [
    (r"counts_per_joint_rev = [0-9.e+]+", "counts_per_joint_rev = inf",
     r"\[joint\.j1\.encoder\] counts_per_joint_rev = inf"),
    (r"counts_per_joint_rev = [0-9.e+]+", "counts_per_joint_rev = 0.0", "counts_per_joint_rev = 0.0: expected 1"),
    (r"gain_a_per_v = [0-9.e+]+", "gain_a_per_v = 0.0", r"\[joint\.j1\.amplifier\] gain_a_per_v = 0.0"),
    (r"volts = \[[^\]]*\]", "volts = [-9.0, nan, 9.0]", r"volts\[1\] = nan: expected a finite number"),
    (r"volts = \[[^\]]*\]", "volts = [-9.0, 1.0, 0.5]", "volts is not strictly monotonic"),
    (r"volts = \[[^\]]*\]\n", "", r"\[joint\.j1\.pot\] has no volts"),
    (r"gain = \[\s*1\.004,", "gain = [1e-300,", r"\[board\.adc1\] gain\[0\] = 1e-300"),
])
def test_a_mangled_value_is_refused_naming_file_table_and_key(valid, pattern, replacement, expected) -> None:
    rig, path = valid
    text, n = re.subn(pattern, replacement, path.read_text(), count=1)
    assert n == 1, pattern
    path.write_text(text)
    with pytest.raises(CalibrationFileError) as e:
        load_store(path, rig)
    assert str(path) in str(e.value)
    assert re.search(expected, str(e.value)), str(e.value)
