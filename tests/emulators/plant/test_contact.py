"""The plant's one-sided contact spring (``Plant.set_contact``): the fingers meeting an object.
Expected values are hand calculations from jpl-arm's hand (gear 50, breakout 0.0015 N·m at the
motor), on both the compiled and the numpy path."""

from __future__ import annotations

import numpy as np
import pytest

from emulators.plant import Plant, load_plant_params

HAND = 6
T = 0.008


def _settle(kernel: str, k_nm_per_rad: float, push_nm: float, seconds: float = 3.0) -> Plant:
    p = Plant(load_plant_params("jpl-arm"), seed=0, kernel=kernel)
    k = np.zeros(p.n_joints)
    k[HAND] = k_nm_per_rad
    at = np.zeros(p.n_joints)
    at[HAND] = 0.4
    p.set_contact(k, at)
    ext = np.zeros(p.n_joints)
    ext[HAND] = -push_nm  # closing: towards 0 rad
    p.set_external_torque(ext)
    cmd = p.idle_command()  # amplifiers off: the H-bridge coasts
    for _ in range(round(seconds / T)):
        p.step_period(cmd, T)
    return p


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_a_push_into_the_contact_spring_rests_at_its_static_deflection(kernel: str) -> None:
    # 5000 N/m across fingers of 0.1 m/rad: 50 N·m/rad at the joint; 0.5 N·m pushes it 10 mrad in,
    # give or take the gearhead's breakout referred to the joint (0.0015 · 50 = 0.075 N·m: ±1.5 mrad)
    p = _settle(kernel, 50.0, 0.5)
    theta = float(p.joint_angle()[HAND])
    assert 0.4 - 0.575 / 50.0 <= theta <= 0.4 - 0.425 / 50.0
    assert np.all(p.joint_angle()[:HAND] == 0.0)  # the other joints have no spring and no push


@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_without_a_contact_spring_the_push_runs_to_the_hard_stop(kernel: str) -> None:
    p = _settle(kernel, 0.0, 0.5)
    assert float(p.joint_angle()[HAND]) == 0.0  # jpl-arm's hand: lower_stop_rad = 0 (closed)


def test_reset_clears_the_contact_spring() -> None:
    p = _settle("numba", 50.0, 0.5, seconds=0.1)
    p.reset()
    assert not p.has_contact and not np.any(p.contact_k_nm_per_rad)
