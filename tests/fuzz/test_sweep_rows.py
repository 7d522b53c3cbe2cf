"""A sweep worker's results (vmehil.analysis.sweep.check_row): a valid row with one value replaced
by garbage, a column deleted or added, or the whole result replaced by garbage. Property: the row
is accepted — and then it is the point's own (index, gains) with every measured value None or
finite and every text a str — or refused with SweepResultError naming the point; nothing else
escapes."""

from __future__ import annotations

import math
from typing import Any

from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz.harness import refused
from vmehil.analysis.sweep import SweepResultError, SweepTask, check_row

GAINS = {"kp": 110.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}
TASK = SweepTask(7, "jpl-arm", 1, GAINS, switch_off=True, plant={"coulomb": 0.12}, sample=3)
#: the row of a simulated point of a tolerance study, written out by hand (docs/sweeps.md's columns)
ROW: dict[str, Any] = {
    "index": 7, **GAINS, "status": "ok", "stable": True, "unstable_reason": None, "sampled_stable": True,
    "phase_margin_deg": 83.6, "gain_margin_db": 16.95, "crossover_hz": 7.17, "bandwidth_hz": 1.04,
    "continuous_phase_margin_deg": 95.3, "lc_amplitude_deg": 0.02, "lc_frequency_hz": 1.5,
    "lc_amplitude_pot_deg": 0.03, "rms_tracking_error_deg": 0.46, "max_tracking_error_deg": 0.99,
    "max_tracking_error_true_deg": 1.14, "settling_time_s": 0.0, "final_error_deg": -0.71, "fault": None,
    "wall_s": 2.5, "switch_off": True, "sample": 3, "plant_coulomb_nm": 0.12}

_garbage = st.one_of(st.none(), st.booleans(), st.integers(-10**20, 10**20), st.floats(allow_nan=True),
                     st.text(max_size=8), st.binary(max_size=4), st.lists(st.floats(), max_size=3),
                     st.dictionaries(st.text(max_size=3), st.integers(), max_size=2), st.just(float("-1e308")))


def _accepted_or_refused(row: Any) -> None:
    try:
        out = check_row(row, TASK)
    except SweepResultError as e:
        assert "point 7" in str(e), str(e)
        refused("SweepResultError")
        return
    assert out["index"] == 7 and all(out[k] == v for k, v in GAINS.items())
    assert isinstance(out["status"], str)
    for k, v in out.items():
        if isinstance(v, float):
            assert math.isfinite(v), (k, v)


@given(key=st.sampled_from(sorted(ROW)), value=_garbage)
def test_a_row_with_one_value_replaced_is_accepted_only_when_sane(key, value) -> None:
    _accepted_or_refused({**ROW, key: value})


@given(drop=st.sets(st.sampled_from(sorted(ROW)), max_size=3),
       add=st.dictionaries(st.text(max_size=12), _garbage, max_size=2))
def test_a_row_with_columns_dropped_or_added_is_refused(drop, add) -> None:
    row = {k: v for k, v in ROW.items() if k not in drop}
    row.update(add)
    _accepted_or_refused(row)


@given(result=_garbage)
def test_any_other_result_is_refused(result) -> None:
    _accepted_or_refused(result)
