"""Servo-loop speed through the full stack: lockstep throughput and real-time tick timing.

(a) **Lockstep** (jpl-arm, melmalec-16): the default demo (`vmehil run`'s coordinated move and
    hold) for ``LOCKSTEP_TICKS`` ticks, simulated seconds per wall second, split into the
    controller side (the servo loop: drivers → emulated boards → law → drivers) and the
    harness exchange (crate clock, sensor nets, the in-process plant step). Baseline, measured
    in the same run: the same rig's plant alone (``Plant.step_period`` with the amplifiers
    enabled and a steady command) — the ratio full stack ÷ plant alone says what the rest of
    the stack costs.
(b) **Real time** (jpl-arm, melmalec-16): :class:`servo.runner.RealtimeRunner` for ``seconds``
    (default 60) of the demo: per-tick compute (p50/p99/max), wake-up lateness (p50/p99/max),
    overruns, and the compute split into controller (what a real HIL controller would run;
    its board accesses here go to the emulated crate) and harness/plant. Goal (issue 5): no
    overruns and controller p99 under 25 % of the 8 ms period for 16 axes.

Run: ``python -m benchmarks bench_servo [--seconds 10]`` or ``python benchmarks/bench_servo.py``.
"""

from __future__ import annotations

import argparse
import sys
import time

from servo.runner import LockstepRunner, RealtimeRunner
from vmehil.session import build_loop
from vmehil.system import build_emulated_rig

RIGS = ("jpl-arm", "melmalec-16")
LOCKSTEP_TICKS = 1250  # 10 s simulated


def _setup(rig: str, n_ticks: int, runner_cls=LockstepRunner, **runner_options):
    system = build_emulated_rig(rig, seed=0)
    loop = build_loop(system, n_ticks=n_ticks)
    loop.start()
    return system, loop, runner_cls(system, loop, **runner_options)


def bench_lockstep(rig: str, n_ticks: int) -> dict[str, float]:
    system, loop, runner = _setup(rig, n_ticks)
    ctrl = harness = 0.0
    t0 = time.perf_counter()
    for _ in range(n_ticks):
        runner.tick()
        ctrl += runner.last_split[0]
        harness += runner.last_split[1]
    wall = time.perf_counter() - t0
    sim = n_ticks * system.rig.period_s
    assert loop.fault is None, loop.fault
    # baseline: this rig's plant alone, amplifiers enabled, a steady small command
    plant = system.plant
    assert plant is not None
    plant.reset()
    cmd = plant.idle_command()
    cmd.amp_enable[:] = True
    cmd.amp_command_v[:] = 0.05
    t0 = time.perf_counter()
    for _ in range(n_ticks):
        plant.step_period(cmd, system.rig.period_s, system.rig.computation_delay_s)
    plant_wall = time.perf_counter() - t0
    system.close()
    return {"sim_per_wall": sim / wall, "plant_alone_sim_per_wall": sim / plant_wall,
            "ratio_vs_plant_alone": plant_wall / wall, "controller_ms_per_tick": ctrl / n_ticks * 1e3,
            "harness_ms_per_tick": harness / n_ticks * 1e3}


def bench_realtime(rig: str, seconds: float) -> dict[str, float]:
    n_ticks = round(seconds * 125.0)
    # the benchmark measures overruns: it counts them instead of stopping at the first 40 ms behind
    system, loop, runner = _setup(rig, n_ticks, RealtimeRunner, overrun="warn")
    runner.run(n_ticks)
    assert loop.fault is None, loop.fault
    s = runner.timing.summary(system.rig.period_s)
    s["joints"] = system.rig.n_joints
    s["ticks_over_5_periods_late"] = runner.late_ticks
    system.close()
    return s


def main(quick: bool = False, seconds: float | None = None) -> list[str]:
    if seconds is None:
        seconds = 10.0 if quick else 60.0
    ticks = 250 if quick else LOCKSTEP_TICKS
    lines = [f"(a) lockstep, full stack, default demo, {ticks} ticks ({ticks * 0.008:g} s simulated)",
             f"{'rig':<12s} {'sim-s/wall-s':>12s} {'plant alone':>12s} {'ratio':>7s} "
             f"{'controller ms/tick':>19s} {'harness ms/tick':>16s}"]
    print("\n".join(lines), flush=True)
    for rig in RIGS:
        r = bench_lockstep(rig, ticks)
        line = (f"{rig:<12s} {r['sim_per_wall']:12.2f} {r['plant_alone_sim_per_wall']:12.2f} "
                f"{r['ratio_vs_plant_alone']:7.2f} {r['controller_ms_per_tick']:19.3f} "
                f"{r['harness_ms_per_tick']:16.3f}")
        print(line, flush=True)
        lines.append(line)
    head = [f"(b) real time, 125 Hz, {seconds:g} s per rig (ms; period 8 ms)",
            f"{'rig':<12s} {'joints':>6s} {'ticks':>6s} {'overruns':>8s} {'compute p50/p99/max':>22s} "
            f"{'controller p50/p99/max':>24s} {'ctrl p99 %T':>11s} {'plant+harness p50/p99':>22s} "
            f"{'lateness p50/p99/max':>22s}"]
    print("\n".join(head), flush=True)
    lines += head
    for rig in RIGS:
        s = bench_realtime(rig, seconds)
        line = (f"{rig:<12s} {s['joints']:6d} {s['ticks']:6d} {s['overruns']:8d} "
                f"{s['compute_p50_ms']:6.2f}/{s['compute_p99_ms']:5.2f}/{s['compute_max_ms']:6.2f}    "
                f"{s['controller_p50_ms']:6.2f}/{s['controller_p99_ms']:5.2f}/{s['controller_max_ms']:6.2f}      "
                f"{s['controller_p99_fraction_of_period'] * 100:10.1f}% "
                f"{s['harness_p50_ms']:10.2f}/{s['harness_p99_ms']:5.2f}      "
                f"{s['lateness_p50_ms']:6.3f}/{s['lateness_p99_ms']:5.3f}/{s['lateness_max_ms']:6.2f}")
        print(line, flush=True)
        lines.append(line)
    return lines


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seconds", type=float, default=None, help="real-time run length per rig (default 60)")
    a = ap.parse_args()
    main(quick=a.quick, seconds=a.seconds)
    sys.exit(0)
