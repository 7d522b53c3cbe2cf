"""CPU cost of a batch of lanes: ``python -m benchmarks.lane_cost B [B ...]``.

B jpl-arm joint-1 sweep points (kp 60…140, default ``SimSettings``: 1 469 ticks) built as
``vmehil.analysis.sweep.evaluate_batch`` builds them (:func:`vmehil.analysis.batch.collector_spared`),
then :func:`vmehil.analysis.lane_batch.simulate_lanes`. Prints the build per run (ms), the lanes
per instance-tick (µs: stack, ticks, per-lane results) and both together; CPU time, so another
job on the machine slows it less than wall time (docs/benchmarks.md, "Lanes: where a tick goes").
Not a ``bench_*`` module: ``python -m benchmarks`` does not run it (a B = 200 batch takes ~10 s).
"""

from __future__ import annotations

import sys
import time

import numpy as np


def measure(size: int) -> str:
    from vmehil.analysis.batch import collector_spared
    from vmehil.analysis.lane_batch import LaneReport, simulate_lanes
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.simulate import SimRun, SimSettings

    clock = time.process_time
    jps = [load_joint("jpl-arm", 1, gains={"kp": float(kp)}) for kp in np.linspace(60.0, 140.0, size)]
    SimRun(jps[0], False, SimSettings()).close()  # the imports and the kernel's load: no run's build
    rep = LaneReport(size)
    with collector_spared() as built:
        t0 = clock()
        runs = [SimRun(jp, False, SimSettings()) for jp in jps]
        t1 = clock()
        built()
        simulate_lanes(runs, report=rep, traces=False)
        t2 = clock()
    n = size * runs[0].n_ticks
    return (f"B={size:3d}: build {1e3 * (t1 - t0) / size:5.1f} ms/run | simulate_lanes {t2 - t1:6.2f} s = "
            f"{1e6 * (t2 - t1) / n:5.1f} us/instance-tick | with the build {1e6 * (t2 - t0) / n:5.1f} "
            f"us/instance-tick | run again alone {len(rep.ejected)}")


def main(argv: list[str] | None = None) -> int:
    sizes = [int(a) for a in (sys.argv[1:] if argv is None else argv)] or [50, 200]
    for b in sizes:
        print(measure(b), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
