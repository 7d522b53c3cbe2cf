"""Tolerance studies: the --vary grammar, the seeded draws, the plant-only perturbation (the
controller keeps its nominal beliefs), and full-stack samples against the nominal run."""

from __future__ import annotations

import math
import tomllib

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from vmehil.analysis.simulate import SimSettings
from vmehil.analysis.sweep import SweepTask, evaluate_point, rig_text, task_rig
from vmehil.analysis.tolerance import (
    PARAMETERS,
    Spread,
    VaryError,
    apply_plant_values,
    draw_samples,
    nominal_values,
    parse_varies,
    parse_vary,
)
from vmehil.analysis.tolerance_report import ThresholdError, parse_thresholds, summarize

FAST = SimSettings(move_deg=2.0, hold_s=1.0, allow_short=True)  # ~1.4 s simulated per run
RIG = rig_text("jpl-arm")
NOMINAL = nominal_values(tomllib.loads(RIG), 1)

spreads = st.builds(Spread, st.sampled_from(sorted(PARAMETERS)), st.sampled_from(["uniform", "normal"]),
                    st.floats(min_value=0, max_value=1e6, allow_nan=False), st.booleans())


@given(spreads)
def test_a_spread_parses_back_from_its_canonical_text(s: Spread) -> None:
    assert parse_vary(s.text()) == s


@given(st.text(max_size=30))
def test_any_text_parses_or_is_a_vary_error(text: str) -> None:
    try:
        s = parse_vary(text)
    except VaryError as e:
        assert "--vary" in str(e)
    else:
        assert s.param in PARAMETERS and s.magnitude >= 0 and math.isfinite(s.magnitude)


@pytest.mark.parametrize("text, expected", [
    ("coulomb=±20%", Spread("coulomb", "uniform", 20.0, True)),
    ("coulomb=+-20 %", Spread("coulomb", "uniform", 20.0, True)),
    ("tach_brush_drop=normal:30%", Spread("tach_brush_drop", "normal", 30.0, True)),
    ("inertia=uniform:0.5", Spread("inertia", "uniform", 0.5, False)),
    ("Brush_Drop=0", Spread("tach_brush_drop", "uniform", 0.0, False)),
])
def test_the_documented_spellings(text: str, expected: Spread) -> None:
    assert parse_vary(text) == expected


@pytest.mark.parametrize("text, words", [
    ("coulomb", "PARAM=SPREAD"), ("stiction=10%", "unknown parameter"), ("coulomb=cauchy:10%", "not uniform"),
    ("coulomb=-10%", "≥ 0"), ("coulomb=nan%", "finite"), ("coulomb=ten%", "not a number"),
])
def test_malformed_spreads_are_clear_errors(text: str, words: str) -> None:
    with pytest.raises(VaryError, match=words):
        parse_vary(text)


def test_a_parameter_twice_and_spreads_leaving_the_range_are_refused() -> None:
    with pytest.raises(VaryError, match="twice"):
        parse_varies(["coulomb=10%", "coulomb=20%"])
    with pytest.raises(VaryError, match="leave the range"):
        draw_samples(parse_varies(["inertia=normal:40%"]), NOMINAL, 1, 0)  # 3σ = 120 %: ≤ 0 kg·m²
    with pytest.raises(VaryError, match="leave the range"):
        draw_samples(parse_varies(["ripple=uniform:0.9"]), NOMINAL, 1, 0)  # 0.22 + 0.9 ≥ 1
    zero = {**NOMINAL, "adc_noise": 0.0}
    with pytest.raises(VaryError, match="percent spread varies nothing"):
        draw_samples(parse_varies(["adc_noise=10%"]), zero, 1, 0)


def test_draws_are_seeded_per_sample_and_stay_within_their_spread() -> None:
    sp = parse_varies(["coulomb=±20%", "tach_brush_drop=normal:10%", "inertia=uniform:0.1"])
    a = draw_samples(sp, NOMINAL, 50, seed=7)
    assert a == draw_samples(sp, NOMINAL, 50, seed=7)
    assert a[:5] == draw_samples(sp, NOMINAL, 5, seed=7)  # sample k does not depend on the count
    assert a != draw_samples(sp, NOMINAL, 50, seed=8)
    c = np.array([d["coulomb"] for d in a]) / NOMINAL["coulomb"]
    assert c.min() >= 0.8 and c.max() <= 1.2 and c.std() > 0.05
    t = np.array([d["tach_brush_drop"] for d in a]) / NOMINAL["tach_brush_drop"]
    assert np.all(np.abs(t - 1) <= 0.3 + 1e-12)
    assert all(abs(d["inertia"] - NOMINAL["inertia"]) <= 0.1 for d in a)
    assert draw_samples(parse_varies(["coulomb=normal:0%"]), NOMINAL, 3, 1) == [{"coulomb": NOMINAL["coulomb"]}] * 3


def test_thresholds_parse_and_count_the_samples_over_them() -> None:
    assert parse_thresholds(["lc_amp_deg=0.5", "settle_s=2"]) == {"lc_amplitude_deg": 0.5, "settling_time_s": 2.0}
    with pytest.raises(ThresholdError, match="METRIC=VALUE"):
        parse_thresholds(["amplitude=0.5"])
    rows = [{"switch_off": False, "lc_amplitude_deg": a, "fault": None} for a in (0.2, 0.6, 0.7, None)]
    rows.append({"switch_off": False, "lc_amplitude_deg": None, "fault": "watchdog"})
    s = summarize(rows, {"lc_amplitude_deg": 0.5})["integrators_on"]
    assert s["thresholds"]["lc_amplitude_deg"] == {"limit": 0.5, "over": 3, "fraction": 3 / 5}
    assert s["metrics"]["lc_amplitude_deg"]["n"] == 3 and s["metrics"]["lc_amplitude_deg"]["p50"] == 0.6


def test_varying_the_plant_never_changes_what_the_controller_believes() -> None:
    """±30 % on every plant parameter: the emulated plant differs, while the controller's scaling,
    normalizing chain and torque limit (from [joint.servo.nominal]) are identical to the nominal rig's."""
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    values = {k: NOMINAL[k] * 1.3 for k in ("coulomb", "viscous", "tach_brush_drop", "inertia", "gear_ratio",
                                            "adc_noise")}
    values["ripple"] = NOMINAL["ripple"] * 0.7
    data = tomllib.loads(RIG)
    perturbed = apply_plant_values(data, 1, values)
    assert perturbed["joint"][0]["servo"] == data["joint"][0]["servo"]  # the nominal tables are untouched
    built = {}
    for name, plant in (("nominal", {}), ("perturbed", values)):
        task = SweepTask(0, "jpl-arm", 1, {}, rig=task_rig(RIG, "jpl-arm", 1, plant), plant=plant)
        system = build_emulated_rig(task.rig)
        try:
            built[name] = (system, build_loop(system))
        finally:
            system.close()
    (sys_n, loop_n), (sys_p, loop_p) = built["nominal"], built["perturbed"]
    assert sys_n.io.scaling == sys_p.io.scaling
    cn, cp = loop_n.controller.active.chain, loop_p.controller.active.chain
    for field in ("j_eff", "ratio", "kt", "amp_gain"):
        np.testing.assert_array_equal(getattr(cn, field), getattr(cp, field))
    limits = [next(o.tau_max for o in lp.controller.active.objects if o.name == "torque_limit")
              for lp in (loop_n, loop_p)]
    np.testing.assert_array_equal(limits[0], limits[1])
    pn, pp = sys_n.params[0], sys_p.params[0]
    assert pp.link.inertia_kg_m2 == pytest.approx(1.3 * pn.link.inertia_kg_m2)
    assert pp.gear.ratio == pytest.approx(1.3 * pn.gear.ratio)
    assert pp.friction.coulomb_nm == pytest.approx(1.3 * pn.friction.coulomb_nm)
    assert pp.friction.breakout_nm == pytest.approx(1.3 * pn.friction.breakout_nm)
    assert pp.tach.brush_drop_v == pytest.approx(1.3 * pn.tach.brush_drop_v)
    assert pp.friction.ripple_fraction == pytest.approx(0.7 * pn.friction.ripple_fraction)
    adc = [b for b in sys_p.crate.boards.values() if type(b).__name__.lower().startswith("adc")]
    assert adc and all(b.noise_rms_v == pytest.approx(1.3 * NOMINAL["adc_noise"]) for b in adc)
    assert sys_n.params[1] == sys_p.params[1]  # the other joints are left alone


@pytest.mark.slow
def test_zero_spread_samples_equal_the_nominal_run_and_a_sample_is_reproducible() -> None:
    """Full stack: a spread of 0 gives every sample the nominal run's figures; a ±30 % sample gives
    the same figures twice and differs from the nominal."""
    gains = {"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}
    figures = [k for k in ("lc_amplitude_deg", "lc_frequency_hz", "rms_tracking_error_deg", "max_tracking_error_deg",
                           "settling_time_s", "final_error_deg", "phase_margin_deg", "status")]
    nominal = evaluate_point(SweepTask(0, "jpl-arm", 1, gains, FAST, rig=task_rig(RIG, "jpl-arm")))
    zero = draw_samples(parse_varies(["coulomb=±0%", "tach_brush_drop=normal:0%"]), NOMINAL, 2, seed=3)
    for k, plant in enumerate(zero):
        row = evaluate_point(SweepTask(k, "jpl-arm", 1, gains, FAST, rig=task_rig(RIG, "jpl-arm", 1, plant),
                                       plant=plant, sample=k))
        assert {f: row[f] for f in figures} == {f: nominal[f] for f in figures}
    wide = draw_samples(parse_varies(["coulomb=±30%", "tach_brush_drop=±30%"]), NOMINAL, 1, seed=3)[0]
    a, b = (evaluate_point(SweepTask(0, "jpl-arm", 1, gains, FAST, rig=task_rig(RIG, "jpl-arm", 1, wide), plant=wide,
                                     sample=0))
            for _ in range(2))
    assert {f: a[f] for f in figures} == {f: b[f] for f in figures}
    assert a["rms_tracking_error_deg"] != nominal["rms_tracking_error_deg"]
    assert a["plant_coulomb_nm"] == wide["coulomb"]
