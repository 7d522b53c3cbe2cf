"""What a trace costs a tick (docs/scope.md, "Cost"): jpl-arm holding, lockstep, the same ticks
without a trace and with ``--trace`` SPECs into files, per-tick wall time (median of rounds run
alternately, so that the machine's load falls on every case alike), the files' sizes, and the
check that the trace made no bus cycle of its own (the crate's counters equal the untraced run's).

Run: ``python -m benchmarks bench_trace [--quick]``.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

from servo.motion import hold_motion
from servo.runner import LockstepRunner
from vmehil.option_groups.trace_options import TraceOptions
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

TICKS = 625  #: 5 s of loop a round
ROUNDS = 5
#: (label, SPEC, file suffixes)
CASES = (
    ("no trace", None, ()),
    ("j*.* (controller) → .mcap", "j*.*", (".mcap",)),
    ("* → .mcap", "*", (".mcap",)),
    ("* → .mcap .vcd .parquet .csv", "*", (".mcap", ".vcd", ".parquet", ".csv")),
)


def one_round(spec: str | None, suffixes: tuple[str, ...], ticks: int, d: Path) -> tuple[float, dict, int]:
    """Seconds per tick, the crate's counters, the files' bytes."""
    system = build_emulated_rig("jpl-arm", seed=0)
    loop = build_loop(system, motion=hold_motion(), n_ticks=ticks)
    runner = LockstepRunner(system, loop)
    trace = None
    with loop.armed():
        if spec is not None:
            paths = tuple(d / f"bench{s}" for s in suffixes)
            trace = TraceOptions(spec, paths).start(system, loop, runner, rig="jpl-arm", err=sys.stderr)
        t0 = time.perf_counter()
        runner.run(ticks)
        wall = time.perf_counter() - t0
    size = 0
    if trace is not None:
        trace.close()
        size = sum(f["bytes"] for f in trace.summary()["files"])
    counters = system.crate.counter_snapshot()
    system.close()
    return wall / ticks, counters, size


def main(quick: bool = False) -> None:
    ticks, rounds = (TICKS // 5, 3) if quick else (TICKS, ROUNDS)
    per_tick: dict[str, list[float]] = {label: [] for label, _s, _x in CASES}
    sizes: dict[str, int] = {}
    counters: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(rounds):
            for label, spec, suffixes in CASES:
                s, c, b = one_round(spec, suffixes, ticks, Path(tmp))
                per_tick[label].append(s)
                sizes[label], counters[label] = b, c
    base = statistics.median(per_tick["no trace"])
    print(f"jpl-arm, lockstep hold, {ticks} ticks a round, median of {rounds} rounds (alternating):")
    for label, _spec, _suffixes in CASES:
        m = statistics.median(per_tick[label])
        extra = f"  +{(m - base) * 1e3:.3f} ms ({m / base - 1:+.0%})" if label != "no trace" else ""
        b = sizes[label]
        size = f", files {b / 1e6:.2f} MB ({b / ticks / 1e3:.1f} kB a tick)" if b else ""
        print(f"  {label:<32} {m * 1e3:.3f} ms a tick{extra}{size}")
    same = all(c == counters["no trace"] for c in counters.values())
    print(f"  bus cycles: {'the same in every case (the trace adds none)' if same else 'DIFFER'}")
