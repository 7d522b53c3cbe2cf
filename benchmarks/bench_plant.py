"""Plant speed: fixed-step plant vs scipy's ``solve_ivp`` on the smooth part of the same equations.

For 1, 6 and 16 joints (copies of jpl-arm joint 1, linear amplifiers) both integrate servo
periods of 8 ms with a new amplifier command each period, as a HIL loop must:

* the plant: :meth:`emulators.plant.Plant.step_period` at 4 kHz (32 exact substeps with
  stick/slip, amplifier, tachometer, encoder events, sensor noise);
* the baseline: ``solve_ivp`` (RK45, rtol 1e-6, atol 1e-9) restarted every period on the smooth
  part of the joint equations — current loop ``di/dt = ωc(i_ref − i)``, ``dθm/dt = ωm``,
  ``J·dωm/dt = Kt·i − (T_c·tanh(ωm/ε) + b·ωm)·(1 + m·sin 2θm)`` (Coulomb regularised, no
  stiction capture, no sensors).

Prints plant substeps per second, simulated seconds per wall second for both, and the ratio
(plant ÷ solve_ivp; > 1 means the plant is faster), and the full jpl-arm rig's speed. The plant
runs its default kernel (the compiled one, :mod:`emulators.plant.kernel`; loaded or compiled
before any timing, and said so) and, for comparison, the numpy path (``VMEHIL_PLANT_KERNEL=numpy``).
Goal (issue "Fast enough to tune"): the plant ≥ 20× solve_ivp for 1, 6 and 16 joints, recorded
with :func:`benchmarks.goals.record`, the baseline from the same run.
Run: ``python -m benchmarks bench_plant`` or ``python benchmarks/bench_plant.py``.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import replace

import numpy as np
from scipy.integrate import solve_ivp

from benchmarks.goals import Goal, record
from emulators.plant import Plant, PlantParams, load_plant_params
from emulators.plant import kernel as plant_kernel

PERIOD = 0.008
GOAL_RATIO = 20.0  #: plant ÷ solve_ivp


def _params(n: int) -> PlantParams:
    j1 = load_plant_params("jpl-arm").joints[0]
    joints = [replace(j1, name=f"j{k + 1}") for k in range(n)]
    return PlantParams(joints=joints)


def _commands(n: int, periods: int) -> np.ndarray:
    t = np.arange(periods)[:, None] * PERIOD
    return 2.0 * np.sin(2 * math.pi * 0.5 * t + np.arange(n)[None, :])  # volts, ±6 A


def bench_plant(n: int, periods: int, params: PlantParams | None = None,
                kernel: str | None = None) -> tuple[float, float]:
    """(substeps per wall second, simulated seconds per wall second)."""
    p = Plant(params or _params(n), kernel=kernel)
    n = p.n_joints
    cmds = _commands(n, periods)
    c = p.idle_command()
    c.amp_enable[:] = True
    c.pwm_duty[:] = 0.3
    t0 = time.perf_counter()
    for k in range(periods):
        c.amp_command_v = cmds[k]
        p.step_period(c, PERIOD)
    wall = time.perf_counter() - t0
    substeps = periods * round(PERIOD * p.rate_hz)
    return substeps / wall, periods * PERIOD / wall


def bench_solve_ivp(n: int, periods: int) -> tuple[float, int]:
    """(simulated seconds per wall second, right-hand-side evaluations)."""
    p = Plant(_params(n))
    fr = p.fr
    gain, wc = p.amp.gain, p.amp.bw_rad_s
    kt, jm = p.Kt, p.J_m
    eps = 0.05  # rad/s: Coulomb regularisation

    def rhs(_t, y, i_ref):
        i, th, w = y[:n], y[n : 2 * n], y[2 * n :]
        r = 1.0 + fr.ripple * np.sin(2.0 * th + fr.ripple_phase)
        tf = (fr.coulomb * np.tanh(w / eps) + fr.viscous * w) * r
        return np.concatenate([wc * (i_ref - i), w, (kt * i - tf) / jm])

    cmds = _commands(n, periods)
    y = np.zeros(3 * n)
    nfev = 0
    t0 = time.perf_counter()
    for k in range(periods):
        i_ref = np.clip(gain * cmds[k], -p.amp.lin_limit, p.amp.lin_limit)
        sol = solve_ivp(rhs, (0.0, PERIOD), y, method="RK45", rtol=1e-6, atol=1e-9, args=(i_ref,))
        y = sol.y[:, -1]
        nfev += sol.nfev
    wall = time.perf_counter() - t0
    return periods * PERIOD / wall, nfev


def main(quick: bool = False) -> list[str]:
    periods = 60 if quick else 250
    t0 = time.perf_counter()
    report = plant_kernel.warm_up() if plant_kernel.choice() == "numba" else "plant kernel: numpy path"
    lines = [
        f"{report} (warm-up {time.perf_counter() - t0:.2f} s, not timed below)",
        f"plant (4 kHz fixed step, exact stick/slip) vs solve_ivp RK45 per 8 ms period; {periods} periods",
        f"{'joints':>6} {'plant substeps/s':>17} {'plant sim-s/s':>14} {'numpy path sim-s/s':>19} "
        f"{'solve_ivp sim-s/s':>18} {'ivp rhs evals':>14} {'ratio':>7}",
    ]
    for line in lines:
        print(line, flush=True)
    ratios = []
    for n in (1, 6, 16):
        steps_s, sim_plant = bench_plant(n, periods)
        _, sim_numpy = bench_plant(n, max(periods // 5, 10), kernel="numpy")
        sim_ivp, nfev = bench_solve_ivp(n, periods)
        lines.append(
            f"{n:>6} {steps_s:>17,.0f} {sim_plant:>14.2f} {sim_numpy:>19.2f} {sim_ivp:>18.2f} {nfev:>14,} "
            f"{sim_plant / sim_ivp:>6.1f}x"
        )
        print(lines[-1], flush=True)
        ratios.append((n, sim_plant, sim_ivp))
    steps_s, sim_plant = bench_plant(7, periods, load_plant_params("jpl-arm"))
    lines.append(f"jpl-arm rig (6 linear + H-bridge hand): {steps_s:,.0f} substeps/s, {sim_plant:.2f} sim-s/s")
    print(lines[-1], flush=True)
    for n, sim_plant, sim_ivp in ratios:
        record(Goal(f"plant vs solve_ivp, {n} joint{'s' if n > 1 else ''}", sim_plant, GOAL_RATIO, "sim-s/s",
                    baseline=sim_ivp, baseline_name="solve_ivp RK45"))
    return lines


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
