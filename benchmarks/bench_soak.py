"""Real-time soak: jpl-arm under :class:`servo.runner.RealtimeRunner` for 10 minutes (``--quick``:
1 minute; ``python -m benchmarks --seconds S`` sets the length), process memory sampled every 10 s.

The motion keeps the arm moving for the whole run: the demo's coordinated quintic move there and
back, 2 s holds between, repeated. Every 1250 ticks (10 s at 125 Hz) the loop's progress callback
reads the process's resident set (``VmRSS`` of ``/proc/self/status``; no extra thread wakes up
beside the loop). Printed: every sample, start (after the first 10 s: the warm-up) / end / max
RSS, faults and overruns. Goals (issue "Fail safe" §5): RSS growth end − start after warm-up
≤ 5 MiB, 0 faults. The run uses the overrun policy ``warn`` (as bench_servo does): overruns on a
loaded machine are counted and reported, not a goal here.

Run: ``python -m benchmarks bench_soak [--quick | --seconds 600]`` or ``python benchmarks/bench_soak.py``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from benchmarks.goals import Goal, record
from servo.motion import DEMO_DELTAS_DEG, Motion, QuinticMove, WaitMove
from servo.runner import RealtimeRunner
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

RIG = "jpl-arm"
SAMPLE_TICKS = 1250  # 10 s at 125 Hz
RSS_GROWTH_GOAL_MIB = 5.0


def rss_kib(status: Path = Path("/proc/self/status")) -> int:
    """This process's resident set size (kiB), from ``VmRSS`` in ``/proc/self/status``."""
    for line in status.read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    raise RuntimeError(f"{status} has no VmRSS line")


def soak_motion(n_joints: int, seconds: float) -> Motion:
    """There and back again (the demo's deltas at speed 0.5), with 2 s holds, repeated to outlast
    ``seconds`` (each leg takes well over 1 s)."""
    deltas = np.deg2rad([DEMO_DELTAS_DEG[j % len(DEMO_DELTAS_DEG)] for j in range(n_joints)])
    legs = int(seconds // 3.0) + 2
    moves = []
    for i in range(legs):
        moves += [QuinticMove(None, deltas if i % 2 == 0 else -deltas, 0.5), WaitMove(2.0)]
    return Motion(tuple(moves), "soak", "<soak>")


def soak(seconds: float) -> dict:
    n_ticks = round(seconds * 125.0)
    system = build_emulated_rig(RIG, seed=0)
    loop = build_loop(system, motion=soak_motion(system.rig.n_joints, seconds), n_ticks=n_ticks)
    runner = RealtimeRunner(system, loop, overrun="warn")
    samples: list[tuple[int, int]] = []  # (tick, RSS kiB)

    def sample(i: int, n: int) -> None:
        if i % SAMPLE_TICKS == 0 or i == n:
            samples.append((i, rss_kib()))
            print(f"  t={i / 125.0:7.1f} s  RSS {samples[-1][1] / 1024:8.2f} MiB", flush=True)

    samples.append((0, rss_kib()))
    try:
        with loop.armed():
            ran = runner.run(n_ticks, progress=sample)
    finally:
        system.close()
    timing = runner.timing.summary(system.rig.period_s)
    rec = loop.recorder
    return {"seconds": seconds, "ticks": ran, "samples": samples, "fault": loop.fault,
            "final_stop": loop.final_stop, "overruns": timing["overruns"], "late_ticks": runner.late_ticks,
            "recorded_rows": rec.rows if rec else 0, "recorder_dropped": rec.dropped if rec else 0,
            "log_dropped": loop.log_dropped, "timing": timing}


def main(quick: bool = False, seconds: float | None = None) -> dict:
    if seconds is None:
        seconds = 60.0 if quick else 600.0
    print(f"real-time soak, {RIG}, {seconds:g} s at 125 Hz, RSS every {SAMPLE_TICKS / 125.0:g} s "
          f"(overrun policy warn)", flush=True)
    r = soak(seconds)
    rss = [kib for _, kib in r["samples"]]
    warm = rss[1] if len(rss) > 2 else rss[0]  # the first 10 s are the warm-up
    growth_mib = (rss[-1] - warm) / 1024
    faults = 0 if r["fault"] is None else 1
    t = r["timing"]
    print(f"  RSS before the run {rss[0] / 1024:.2f} MiB; after warm-up (start) {warm / 1024:.2f} MiB; "
          f"end {rss[-1] / 1024:.2f} MiB; max {max(rss) / 1024:.2f} MiB; growth end-start {growth_mib:+.2f} MiB")
    print(f"  ticks {r['ticks']}; faults {faults}{'' if r['fault'] is None else ' (' + str(r['fault']) + ')'}; "
          f"overruns {r['overruns']}; ticks > 5 periods late {r['late_ticks']}; "
          f"compute p50/p99/max {t['compute_p50_ms']:.2f}/{t['compute_p99_ms']:.2f}/{t['compute_max_ms']:.2f} ms; "
          f"recorder rows {r['recorded_rows']} (dropped {r['recorder_dropped']}); log dropped {r['log_dropped']}; "
          f"final stop {r['final_stop']['reason'] if r['final_stop'] else None}", flush=True)
    record(Goal(f"soak {seconds:g} s: RSS growth end - start after warm-up", growth_mib, RSS_GROWTH_GOAL_MIB,
                "MiB", "at_most"))
    record(Goal(f"soak {seconds:g} s: faults", faults, 0, "", "at_most"))
    return r


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--seconds", type=float, default=None, help="soak length (default 600; --quick 60)")
    a = ap.parse_args()
    main(quick=a.quick, seconds=a.seconds)
    sys.exit(0)
