"""The velocity filter alternative to KvI (servo.control.velocity_filter): the law and the
gain guard's sampled loop use one definition (the tuning model: tests/vmehil/analysis/
test_velocity_filter_model.py); expected values from the
filter's formula (ef_k = ef_{k−1} + α·(e_k − ef_{k−1}), α = 1 − exp(−2π·f_c·T)), written here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from servo.control.gains import Gains
from servo.control.law import PidLaw, SwitchOffConfig
from servo.control.linear import sampled_loop_matrix
from servo.gain_guard import judge


def _alpha(fc_hz: float, T: float) -> float:  # the paper-independent formula, written out here
    return 1.0 - math.exp(-2.0 * math.pi * fc_hz * T)


def test_filtered_kvi_channel_follows_a_constant_error_as_a_first_order_lag():
    T, fc, e0 = 0.008, 5.0, 0.01
    g = Gains(kp=100.0, kpi=0.0, kv=0.0, kvi=1000.0)
    law = PidLaw(1, T, g, SwitchOffConfig.disabled(1), filter_hz=np.array([fc]))
    al = _alpha(fc, T)
    assert al == pytest.approx(0.22223, abs=1e-5)  # 1 − e^(−0.25133) = 1 − 0.77777
    for k in range(40):
        a = law.update(np.array([0.0]), np.array([0.0]), np.array([e0]), np.array([0.0]), motion_done=False)
        ef = e0 * (1.0 - (1.0 - al) ** (k + 1))
        assert a[0] == pytest.approx(100.0 * e0 + 1000.0 * ef, rel=1e-12)
    assert law.state.iv[0] == 0.0  # no integral of ė is kept where the filter serves


def test_without_a_filter_the_law_integrates_the_velocity_error_as_before():
    T = 0.008
    law = PidLaw(1, T, Gains(kp=0.0, kpi=0.0, kv=0.0, kvi=1000.0), SwitchOffConfig.disabled(1))
    for k in range(5):
        a = law.update(np.array([0.0]), np.array([0.0]), np.array([0.0]), np.array([0.5]))
        assert a[0] == pytest.approx(1000.0 * 0.5 * T * (k + 1), rel=1e-12)
    assert not law.filtered.any()


def test_the_guard_loop_takes_the_laws_filter():
    T, fc = 0.008, 4.0
    g = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    # the guard's sampled loop: a fourth state ef with pole 1 − α fed by α·e
    A = sampled_loop_matrix(g.kp, g.kpi, g.kv, g.kvi, T, 0.0, filter_alpha=_alpha(fc, T))
    assert A[3, 3] == pytest.approx(1.0 - _alpha(fc, T)) and A[3, 0] == pytest.approx(-_alpha(fc, T))


def test_guard_judges_the_filtered_loop_not_the_integrating_one():
    T, delay = 0.008, 0.125
    # Kpi = 0 with KvI > 0 is marginal only when KvI integrates ė (a pole at z = 1); the filter is no integrator
    no_kpi = Gains(kp=100.0, kpi=0.0, kv=50.0, kvi=1000.0)
    assert not judge(no_kpi, T, delay).ok
    assert judge(no_kpi, T, delay, filter_hz=5.0).ok
    # a low corner under a large KvI: the filter's lag makes the loop unstable, and the guard says so
    v = judge(Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1e5), T, delay, filter_hz=0.5)
    assert not v.ok and v.kind == "unstable" and "pole radius" in v.reason


def test_auto_boost_adds_nothing_for_a_filtered_joint():
    g = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    law = PidLaw(2, 0.008, g, SwitchOffConfig.make(2), filter_hz=np.array([np.nan, 5.0]))
    # auto: Kp + KvI where KvI integrates ė (its stiffness is lost when frozen); Kp where the filter keeps running
    assert list(law.kp_off()) == [1100.0, 100.0]
