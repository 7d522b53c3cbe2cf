"""PidLaw.switch_joint: one joint's gains and velocity filter switched at the next tick,
bumpless — the law's output in the switch tick is the old law's (written out here from the law's
formula), but for the change of Kv on that tick's velocity error."""

from __future__ import annotations

import numpy as np
import pytest

from servo.control.gains import Gains
from servo.control.law import PidLaw, SwitchOffConfig


def _loaded_law() -> tuple[PidLaw, np.ndarray]:
    """A law holding a load: integrators charged, switch-off disabled (always integrating)."""
    law = PidLaw(2, 0.008, Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0), SwitchOffConfig.disabled(2))
    law.state.ie[:] = [0.001, 0.002]  # Kpi·Ie = 5 and 10 rad/s²: the load's share
    law.state.iv[:] = [0.0004, -0.0003]
    return law, np.array([0.0021, -0.0013])


def test_a_switch_keeps_the_output_but_for_the_velocity_term():
    law, e = _loaded_law()
    z = np.zeros(2)
    edot = np.array([0.03, -0.02])
    old = Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0)
    # what the old law commands this tick, by hand (integrators fed with T·e and T·ė first)
    T = 0.008
    ie, iv = law.state.ie + T * e, law.state.iv + T * edot
    a_old = old.kp * e + old.kpi * ie + old.kv * edot + old.kvi * iv
    new = Gains(kp=200.0, kpi=10000.0, kv=60.0, kvi=2000.0)
    law.switch_joint(1, new)
    a = law.update(z, -edot, e, z, tick=0)
    assert a[0] == pytest.approx(a_old[0], rel=1e-12)  # joint 1 untouched
    # joint 2: the same output but for the change of the velocity gain on this tick's ė
    assert a[1] == pytest.approx(a_old[1] + (new.kv - old.kv) * edot[1], rel=1e-9)
    assert list(law.gains.kp) == [100.0, 200.0]


def test_a_switch_to_the_filter_primes_it_and_stays_bumpless():
    law, e = _loaded_law()
    z = np.zeros(2)
    before = law.update(z, z, e, z, tick=0)
    law.switch_joint(0, Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0), 5.0)
    after = law.update(z, z, e, z, tick=1)
    assert law.filtered.tolist() == [True, False]
    # the errors did not change: joint 1's output moves only by this tick's integration T·Kpi·e
    assert after[0] - before[0] == pytest.approx(0.008 * 5000.0 * e[0], rel=1e-9)




def test_a_bad_switch_is_refused_when_staged_not_inside_the_tick():
    from servo.control.errors import GainError

    law, _ = _loaded_law()
    with pytest.raises(GainError):
        law.switch_joint(0, Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0), -5.0)
    with pytest.raises(GainError):
        law.switch_joint(2, Gains(kp=100.0, kpi=5000.0, kv=50.0, kvi=1000.0))
    assert law._pending_switch == {}
