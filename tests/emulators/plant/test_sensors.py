"""Sensor models: potentiometer non-linearity, tachometer dead band, encoder events."""

from __future__ import annotations

import itertools
import math
from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from emulators.plant import Plant, PlantParams, encoder_events, load_plant_params

T = 0.008


def _j1(**kw):
    j = load_plant_params("jpl-arm").joints[0]
    return replace(j, **kw) if kw else j


def test_pot_nonlinearity_is_a_few_tenths_of_a_percent_and_nine_points_fix_it():
    p = Plant(PlantParams(joints=[_j1()]))
    span = p.pot.span[0]
    theta = np.linspace(-span / 2, span / 2, 3401)
    v = np.array([p.pot.volts(np.array([t]))[0] for t in theta])
    # deviation from the end-point line, as a fraction of span
    line = v[0] + (v[-1] - v[0]) * (theta - theta[0]) / (theta[-1] - theta[0])
    dev = np.max(np.abs(v - line)) / (v[-1] - v[0])
    assert 0.002 <= dev <= 0.006
    # the paper's calibration: nine readings 45° apart, eight linear segments
    pts = np.radians(np.arange(-180.0, 181.0, 45.0))
    pts = np.clip(pts, theta[0], theta[-1])
    vp = np.array([p.pot.volts(np.array([t]))[0] for t in pts])
    inside = (theta > pts[0]) & (theta < pts[-1])
    est = np.interp(v[inside], vp, pts)
    err = np.max(np.abs(est - theta[inside]))
    naive = np.max(np.abs(np.interp(v, [v[0], v[-1]], [theta[0], theta[-1]]) - theta))
    assert err < naive / 4
    assert err < math.radians(0.06)  # ≈ 3.6 arcmin


def test_pot_gradient_gives_a_12_bit_count_of_about_1_45_mrad():
    p = Plant(PlantParams(joints=[_j1()]))
    volts_per_rad = (p.pot.v_high[0] - p.pot.v_low[0]) / p.pot.span[0]
    lsb_v = 20.0 / 4096
    asse = lsb_v / volts_per_rad
    assert 1.40e-3 < asse < 1.50e-3


def _tach_at(speed_joint: float, **tach):
    j = _j1()
    j = replace(j, tach=replace(j.tach, noise_v=0.0, ripple_fraction=0.0, **tach),
                friction=replace(j.friction, breakout_nm=0.0, coulomb_nm=0.0, viscous_nm_s_per_rad=0.0),
                link=replace(j.link, lower_stop_rad=-1e6, upper_stop_rad=1e6))
    p = Plant(PlantParams(joints=[j]))
    p.omega_m = np.array([speed_joint * j.gear.ratio])  # frictionless, unpowered: constant speed
    for _ in range(5):
        s = p.step_period(p.idle_command(), T)
    return s.tach_v[0], s.truth["omega_joint"][0]


def test_tach_is_blind_inside_its_brush_drop_dead_band_and_linear_outside():
    for w in (0.02, 0.08, 0.119, -0.11):
        v, w_true = _tach_at(w)
        assert math.isclose(w_true, w, rel_tol=1e-12)
        assert v == 0.0
    for w in (0.2, 1.0, -0.5):
        v, _ = _tach_at(w)
        assert math.isclose(v, math.copysign(abs(w) * 1.0 - 0.12, w), rel_tol=1e-6)
    v, _ = _tach_at(0.05, brush_drop_v=0.0)  # an ideal tach reads low speeds
    assert math.isclose(v, 0.05, rel_tol=1e-6)


def test_tach_noise_and_offset_appear_at_sampling():
    j = _j1()
    j = replace(j, tach=replace(j.tach, offset_v=0.01))
    p = Plant(PlantParams(joints=[j]), seed=9)
    v = np.array([p.step_period(p.idle_command(), T).tach_v[0] for _ in range(400)])
    assert math.isclose(v.mean(), 0.01, abs_tol=0.0005)
    assert 0.0015 < v.std() < 0.0025


def test_encoder_counts_follow_the_motor_angle_with_one_index_per_revolution():
    j = _j1()
    p = Plant(PlantParams(joints=[j]))
    c = p.idle_command()
    c.amp_enable[0] = True
    c.amp_command_v[0] = 3.0
    total, index_positions = 0, []
    for _ in range(150):
        s = p.step_period(c, T)
        ev = s.encoder[0]
        index_positions += [total + o for o in ev.index_offsets]
        total += ev.counts
        assert ev.illegal == 0
        assert ev.phase == total % 4
    cpr = 4 * j.encoder.lines_per_rev
    assert total == math.floor(s.truth["theta_motor"][0] * cpr / (2 * math.pi))
    assert total > 3 * cpr
    assert index_positions == list(range(cpr, total + 1, cpr))


def test_encoder_adapter_reports_illegal_transitions_when_too_fast():
    # 10 x4 states per decoder sample: mostly aliased/illegal
    x = np.linspace(0.0, 1000.0, 33)[:, None]
    ev = encoder_events(x, dt=1e-6 / 32 * 100 / 1, sample_hz=1e6, index_period_x4=2000, index_phase_x4=0)[0]
    assert ev.illegal > 0
    assert ev.counts != 1000
    slow = encoder_events(x, dt=1.0, sample_hz=1e6, index_period_x4=2000, index_phase_x4=0)[0]
    assert slow.counts == 1000 and slow.illegal == 0 and slow.phase == 0


def test_encoder_adapter_two_states_per_sample_are_illegal():
    x = np.array([[0.5], [2.5], [4.5], [6.5]])  # exactly 2 states per decoder sample
    ev = encoder_events(x, dt=1e-6, sample_hz=1e6, index_period_x4=100, index_phase_x4=50)[0]
    assert ev.illegal == 3 and ev.counts == 0 and ev.phase == 2


@settings(max_examples=200, deadline=None)
@given(
    start=st.floats(-5000.0, 5000.0),
    steps=st.lists(st.floats(-3.0, 3.0), min_size=1, max_size=40),
    period=st.integers(4, 400),
    phase=st.integers(0, 399),
)
def test_encoder_adapter_slow_motion_counts_and_index_crossings(start, steps, period, phase):
    x = start + np.concatenate(([0.0], np.cumsum(steps)))
    ev = encoder_events(x[:, None], dt=1e-4, sample_hz=1e6, index_period_x4=period, index_phase_x4=phase)[0]
    f = np.floor(x).astype(int)
    assert ev.counts == f[-1] - f[0]
    assert ev.illegal == 0
    # every reported index lies on an index position, and the net number of upward minus
    # downward crossings equals the change in the number of index positions passed
    for off in ev.index_offsets:
        assert (f[0] + off - phase) % period == 0
    n_up = sum(1 for a, b in itertools.pairwise(f) for p in range(a + 1, b + 1) if (p - phase) % period == 0)
    n_dn = sum(1 for a, b in itertools.pairwise(f) for p in range(b + 1, a + 1) if (p - phase) % period == 0)
    assert len(ev.index_offsets) == n_up + n_dn
