"""The black box's cost on the servo tick (issue #35: at most 5 %).

Per rig (jpl-arm, melmalec-16), lockstep, the default demo: the same loop ticks in alternating
blocks of ``BLOCK`` ticks with its black box (:mod:`servo.blackbox`) and without it
(``loop.blackbox = None``), so both see the same machine, the same motion phases and the same
caches; the order is ABBA (with, without, without, with, …) so a drift in the machine's load
falls on both. Figures per tick, in **thread CPU time** (``time.thread_time``: the time this
thread ran, so another job preempting it on a shared machine does not count): the controller
side (:meth:`servo.loop.ServoLoop.tick`: drivers → law → drivers, where the box's row is
written — what a real rig runs) and the whole tick (controller + harness + plant), each the
median over blocks of the block's mean. The baseline is the same run's blocks without the box;
the goal is the controller side with the box ≤ 1.05 × without. The box's own ``put`` is also
timed alone (µs per call, the median of 5 repeats of 2 000 calls with a real tick's row) and
shown as a share of the controller's tick without the box: the same cost, less noisy.

Run: ``python -m benchmarks bench_blackbox`` (``--quick``: fewer blocks).
"""

from __future__ import annotations

import statistics
import time

import numpy as np

from benchmarks.goals import Goal, record
from servo.runner import LockstepRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

RIGS = ("jpl-arm", "melmalec-16")
BLOCK = 125  #: ticks per block (1 s of loop time)
GOAL = 1.05  #: controller side with the box ÷ without, at most


def bench_rig(rig: str, blocks: int) -> dict[str, float]:
    system = build_emulated_rig(rig, seed=0)
    loop = build_loop(system, n_ticks=2 * blocks * BLOCK + BLOCK)
    runner = LockstepRunner(system, loop)
    box = loop.blackbox
    assert box is not None
    clock = time.thread_time
    in_loop = [0.0]
    tick = loop.tick

    def timed_tick(truth=None) -> None:  # the controller side, in this thread's CPU time
        t0 = clock()
        tick(truth=truth)
        in_loop[0] += clock() - t0

    loop.tick = timed_tick  # type: ignore[method-assign]
    loop.start()
    for _ in range(BLOCK):  # warm-up (first reads, caches, the law's first ticks)
        runner.tick()
    ctrl: dict[bool, list[float]] = {True: [], False: []}
    whole: dict[bool, list[float]] = {True: [], False: []}
    for b in range(2 * blocks):
        keep = b % 4 in (0, 3)  # ABBA
        loop.blackbox = box if keep else None
        in_loop[0] = 0.0
        t0 = clock()
        for _ in range(BLOCK):
            runner.tick()
        whole[keep].append((clock() - t0) / BLOCK)
        ctrl[keep].append(in_loop[0] / BLOCK)
    loop.blackbox = box
    loop.tick = tick  # type: ignore[method-assign]
    assert loop.fault is None, loop.fault
    put_us = _time_put(loop)
    system.close()
    out = {"joints": float(system.rig.n_joints), "put_us": put_us}
    for keep, name in ((True, "with"), (False, "without")):
        out[f"ctrl_{name}_ms"] = statistics.median(ctrl[keep]) * 1e3
        out[f"tick_{name}_ms"] = statistics.median(whole[keep]) * 1e3
    return out


def _time_put(loop) -> float:
    """µs per :meth:`servo.blackbox.BlackBox.put` with the loop's last row (median of 5 × 2 000)."""
    box = loop.blackbox
    row = {k: v for k, v in loop.last.items() if isinstance(v, np.ndarray)}
    law = loop.law
    brakes = loop.io.brake_released
    fault = np.zeros(loop.n)
    times = []
    for _ in range(5):
        t0 = time.thread_time()
        for k in range(2000):
            box.put(k, k * loop.period_s, row, 0, integrator_e=law.state.ie, integrator_v=law.state.iv,
                    enabled=True, brake_released=brakes, amp_fault=fault, stop_tick=None)
        times.append((time.thread_time() - t0) / 2000)
    return statistics.median(times) * 1e6


def main(quick: bool = False) -> list[str]:
    blocks = 4 if quick else 12
    lines = [f"black box on the tick: lockstep, default demo, {blocks} blocks of {BLOCK} ticks with and {blocks} "
             "without, ABBA (thread CPU ms per tick, medians of the blocks' means; put: µs per row and its share "
             "of the controller's tick without the box)",
             f"{'rig':<12s} {'joints':>6s} {'ctrl with':>10s} {'ctrl w/o':>9s} {'ctrl +%':>8s} {'tick with':>10s} "
             f"{'tick w/o':>9s} {'tick +%':>8s} {'put µs':>7s} {'put %':>6s}"]
    print("\n".join(lines), flush=True)
    for rig in RIGS:
        r = bench_rig(rig, blocks)
        c = (r["ctrl_with_ms"] / r["ctrl_without_ms"] - 1) * 100
        w = (r["tick_with_ms"] / r["tick_without_ms"] - 1) * 100
        line = (f"{rig:<12s} {int(r['joints']):6d} {r['ctrl_with_ms']:10.4f} {r['ctrl_without_ms']:9.4f} {c:+8.2f} "
                f"{r['tick_with_ms']:10.4f} {r['tick_without_ms']:9.4f} {w:+8.2f} {r['put_us']:7.2f} "
                f"{r['put_us'] / 10 / r['ctrl_without_ms']:6.2f}")
        print(line, flush=True)
        lines.append(line)
        record(Goal(f"black box, {rig}: controller side per tick with the box", r["ctrl_with_ms"], GOAL, "ms",
                    kind="at_most", baseline=r["ctrl_without_ms"], baseline_name="the same run's blocks without it"))
    return lines


if __name__ == "__main__":
    main()
