"""The integrator switch-off state machine runs over all joints as arrays: the same states, band
timers and events (in joint order) as stepping each joint on its own."""

from __future__ import annotations

import numpy as np

from servo.control.law import PidLaw, SwitchEvent, SwitchOffConfig

T = 0.008


def _reference_step(law: PidLaw, e: np.ndarray, done: np.ndarray, events: list[SwitchEvent], tick: int) -> None:
    """One joint at a time, as PidLaw._switch_off_step did before it worked on arrays."""
    st, so = law.state, law.switch_off
    abs_e = np.abs(e)
    crossed = so.zero_crossing & np.isfinite(st.e_prev) & (e * np.nan_to_num(st.e_prev) < 0)

    def event(j: int, integrating: bool, reason: str) -> None:
        st.integrating[j] = integrating
        events.append(SwitchEvent(tick, j, integrating, reason))

    for j in range(law.n):
        if not so.enabled[j]:
            if not st.integrating[j]:
                event(j, True, "disabled")
            st.in_band_time[j] = 0.0
            continue
        if st.integrating[j]:
            if done[j] and (abs_e[j] <= so.inner_band[j] or crossed[j]):
                if st.in_band_time[j] + 1e-12 >= so.settle_time[j]:
                    event(j, False, "settled")
                    st.in_band_time[j] = 0.0
                else:
                    st.in_band_time[j] += T
            else:
                st.in_band_time[j] = 0.0
        else:
            if not done[j]:
                event(j, True, "new_motion")
            elif abs_e[j] > so.outer_band[j]:
                event(j, True, "error_outside_band")


def test_switch_off_arrays_match_joint_by_joint() -> None:
    rng = np.random.default_rng(7)
    n = 6
    so = SwitchOffConfig.make(n, enabled=[True, True, True, True, False, True], inner_band=1e-3,
                              outer_band=5e-3, settle_time=[0.0, 0.02, 0.05, 0.0, 0.0, 0.03],
                              zero_crossing=[True, False, True, True, True, False])
    fast, ref = PidLaw(n, T, switch_off=so), PidLaw(n, T, switch_off=so)
    ref_events: list[SwitchEvent] = []
    changes = 0
    for k in range(3000):
        e = rng.normal(0.0, 3e-3, n) * (1.0 if k % 400 < 300 else 0.1)
        e[rng.random(n) < 0.01] = np.nan  # a bad reading now and then
        done = rng.random(n) < 0.9
        if k == 1500:  # a joint's switch-off disabled while it is frozen: it resumes ("disabled")
            so2 = SwitchOffConfig.make(n, enabled=[True, False, True, True, False, True], inner_band=1e-3,
                                       outer_band=5e-3, settle_time=[0.0, 0.02, 0.05, 0.0, 0.0, 0.03],
                                       zero_crossing=[True, False, True, True, True, False])
            fast.switch_off = ref.switch_off = so2
        fast._tick = k
        fast._switch_off_step(e, done)
        fast.state.e_prev = e.copy()
        _reference_step(ref, e, done, ref_events, k)
        ref.state.e_prev = e.copy()
        assert fast.state.integrating.tobytes() == ref.state.integrating.tobytes(), k
        assert fast.state.in_band_time.tobytes() == ref.state.in_band_time.tobytes(), k
        changes = len(ref_events)
    assert fast.events == ref_events
    reasons = {ev.reason for ev in ref_events}
    assert changes > 100 and {"settled", "new_motion", "error_outside_band"} <= reasons
