"""The fault matrix (vmehil.fault_matrix): every fault of the catalogue on jpl-arm (lockstep, seed 0,
injected at tick 100 of the demo move, 400 ticks) ends as docs/faults.md says — the stop's cause
within its tick bound and under its true-error bound, or no stop where that is the documented
outcome."""

from __future__ import annotations

import pytest

from tests.support import REPO
from vmehil.fault_matrix import MATRIX, MatrixCase, outcome_ok, run_case
from vmehil.fault_scenarios.injection import CATALOGUE

DOC = REPO / "docs" / "faults.md"


# The CAN cases run the plant node over a bus with wall-clock answer timeouts (2-3 s each): slow.
_CASES = [pytest.param(c, marks=pytest.mark.slow) if c.spec.startswith("can_") else c for c in MATRIX]


@pytest.mark.parametrize("case", _CASES, ids=[c.spec for c in MATRIX])
def test_each_fault_ends_as_documented(case: MatrixCase) -> None:
    got = run_case(case)
    assert outcome_ok(case, got) == [], got
    assert got["injected_faults"][0]["tick"] == 100


def test_the_matrix_covers_every_fault_of_the_catalogue_and_the_doc_lists_every_case() -> None:
    assert {c.name for c in MATRIX} == set(CATALOGUE)
    doc = DOC.read_text()
    for case in MATRIX:
        assert f"`{case.spec}`" in doc, case.spec
    assert "python -m vmehil.fault_matrix" in doc


def test_a_stop_later_than_20_ticks_or_after_more_than_1_2_degrees_of_movement_is_not_as_documented() -> None:
    # the matrix passed anything within 50 ticks and 3° of true error (most of it the pots' bow)
    # while docs/faults.md claimed "within 20 ticks, under 1.2°"
    case = MatrixCase("pot_frozen:joint=j1", "position_mismatch", "")
    ok = {"stopped": True, "cause": "position_mismatch", "ticks_after_fault": 17, "true_movement_deg": 0.88,
          "true_error_deg": 0.26}
    assert outcome_ok(case, ok) == []
    assert outcome_ok(case, {**ok, "ticks_after_fault": 25}) == ["stopped 25 ticks after the fault (limit 20)"]
    assert outcome_ok(case, {**ok, "true_movement_deg": 1.5}) == [
        "the arm moved 1.5° from the fault to the stop (limit 1.2°)"]
