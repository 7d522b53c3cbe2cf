"""The tuning model's servo law with the velocity filter alternative to KvI
(vmehil.analysis.loop_model, ``kvi_filter_hz``) against the servo's own PidLaw, tick by tick:
one definition (servo.control.velocity_filter) in both."""

from __future__ import annotations

import numpy as np
import pytest

from servo.control.gains import Gains
from servo.control.law import PidLaw, SwitchOffConfig


def test_the_tuning_models_sampled_controller_is_the_laws_filtered_law():
    pytest.importorskip("control")
    from vmehil.analysis.loop_model import sampled_controller

    T, fc = 0.008, 4.0
    g = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    law = PidLaw(1, T, g, SwitchOffConfig.disabled(1), filter_hz=np.array([fc]))
    K = sampled_controller(g, T, "tach", kvi_filter_hz=fc)
    rng = np.random.default_rng(3)
    r, rv = rng.normal(0, 0.01, 60), rng.normal(0, 0.05, 60)
    x = np.zeros(K.nstates)
    for k in range(60):
        u = np.array([r[k], rv[k], 0.0, 0.0])
        y = float((K.C @ x + K.D @ u)[0])
        x = K.A @ x + K.B @ u
        a = law.update(np.array([0.0]), np.array([0.0]), np.array([r[k]]), np.array([rv[k]]))
        assert y == pytest.approx(a[0], rel=1e-9, abs=1e-12)
