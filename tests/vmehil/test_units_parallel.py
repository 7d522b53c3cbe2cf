"""MELMALEC's five unit controllers in parallel (threads, one plant in lockstep): the key check
is bit-identity with the single controller of all sixteen joints for the same seed."""

from __future__ import annotations

import numpy as np

from servo.runner import LockstepRunner
from vmehil.session import build_loop
from vmehil.system import build_emulated_rig
from vmehil.units.coordinator import run_units

N_TICKS = 250


def single_run(seed: int, n_ticks: int) -> dict[str, np.ndarray]:
    system = build_emulated_rig("melmalec-16", seed=seed)
    loop = build_loop(system, n_ticks=n_ticks)
    with loop.armed():
        LockstepRunner(system, loop).run(n_ticks)
    assert loop.fault is None
    system.close()
    return loop.recorder.trimmed()


def test_parallel_units_in_lockstep_equal_the_single_controller_bit_for_bit() -> None:
    ref = single_run(3, N_TICKS)
    run = run_units("melmalec-16", seed=3, n_ticks=N_TICKS)
    try:
        assert all(u.error is None and u.completed == N_TICKS for u in run.units)
        assert all(u.loop.fault is None for u in run.units)
        got = run.recorded()
        for key in ref:
            if key == "compute_s":
                continue
            assert np.array_equal(ref[key], got[key], equal_nan=True), key
        moved = np.degrees(np.abs(got["theta_true"][-1] - got["theta_true"][0]))
        assert np.all(moved > 1.0)  # every joint really moved: the check compares motion, not rest
        assert run.hub.exchanges == N_TICKS + 1  # power-up + one per tick, each with every unit in
    finally:
        run.close()
