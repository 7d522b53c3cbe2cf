"""Calibration files (vmehil.calibration.store.load_store): a valid file with one value replaced
by garbage, a key or table deleted, an unknown key added, or its text corrupted. Property: the
file loads — and then every value the drivers use is finite — or is refused with
CalibrationFileError naming the file; nothing else escapes."""

from __future__ import annotations

import math
import re
import tomllib

import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz.harness import refused
from tests.fuzz.mutate import mutated
from tests.support.calib_bench import sample_store, write_rig
from vmehil.calibration.store import (
    CalibrationFileError,
    load_store,
)


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    folder = tmp_path_factory.mktemp("calibration")
    rig = write_rig(folder)
    path = sample_store(rig).save(folder / "cal.toml")
    return rig, path


def _load_or_refuse(rig, path) -> None:
    try:
        store = load_store(path, rig)
    except CalibrationFileError as e:
        assert str(path) in str(e) and e.reason, str(e)
        refused("CalibrationFileError")
        return
    # what loads is applicable: every joint value the drivers use is finite
    for entries in store.joints.values():
        for entry in entries.values():
            for v in entry.values.values():
                for x in v if isinstance(v, list | tuple) else [v]:
                    assert not isinstance(x, float) or math.isfinite(x), (entry, v)


_garbage = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10**12, 10**12),
                     st.text(max_size=5), st.booleans(), st.lists(st.floats(), max_size=4))


@given(key=st.sampled_from(["counts_per_joint_rev", "gain_a_per_v", "offset_a", "volts", "angles_rad",
                            "offset_v", "gain", "board_id", "base"]), value=_garbage)
def test_any_mangled_value_loads_or_is_refused_typed(valid, key, value) -> None:
    import tomli_w

    rig, path = valid
    text = path.read_text()
    line = tomli_w.dumps({key: value}).strip() if value == value else f"{key} = nan"
    text = re.sub(rf"^{key} = (?:\[[^\]]*\]|[^\n]*)", line.replace("\\", "\\\\"), text, count=1, flags=re.M)
    bad = path.with_name("mangled.toml")
    bad.write_text(text)
    _load_or_refuse(rig, bad)


@given(data=st.data())
def test_a_mangled_calibration_file_loads_or_is_refused_naming_the_file(valid, data) -> None:
    rig, path = valid
    text = path.read_text()
    raw = data.draw(mutated(text, tomllib.loads(text)), label="file")
    bad = path.with_name("mutated.toml")
    bad.write_bytes(raw)
    _load_or_refuse(rig, bad)
