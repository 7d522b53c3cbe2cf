"""The tools' speed: gain sweep, limit-cycle analysis, calibration, and ``vmehil run``'s cold start.

Every figure is the wall time of the real command in a fresh process (``python -m vmehil ...``,
the default rig jpl-arm, seed 0, ``--quiet``, outputs in a temporary folder), as a user runs it:

* ``tune sweep --grid kp=80:140:20,kvi=600:1400:20`` (400 points, one worker per core) — with
  ``--quick`` a 4-point grid of the same ranges, its time scaled by points (×100; the goal's
  name says so); the same small grid with ``--jobs 1`` is printed next to it;
* ``tune limit-cycle`` (prediction and both full-stack runs, side by side) — and ``--jobs 1``
  (the runs one after the other in one process) next to it;
* ``calibrate all --auto`` (adc, dac, encoder, amplifier, pot; reference fixture);
* batched lockstep (issue 34, ``--batch``): the same sweep with ``--batch auto`` (the default: batches
  of lanes) beside ``--batch 1``; a Monte Carlo of a 10 s hold (``--vary coulomb=±20%``) over 512
  samples in batches of 256 (the size ``--batch auto`` gives a 10 000-sample study on 2 cores; 64 in
  batches of 32 with ``--quick``) and with ``--batch 1`` over 40 (8), each scaled to 10 000 samples
  (per sample, a batch costs what the full study's batches of the same size cost; a scalar run costs
  the same each); the peak resident memory of one process
  running B = 400 instances as one rig of lanes to the end (40 with ``--quick``, scaled ×10); and a
  single run's speed (``simulate``, jpl-arm, 10 s hold, in this process: simulated seconds per CPU
  second), the scalar path every single run takes;
* ``run --duration 0.008``: launch to the end of a one-tick run — an upper bound of the time to
  the first tick (it adds the tick, the summary and the teardown); and ``run --help`` with the
  interpreter's import time (``-X importtime``) of ``vmehil run --help``.

The goals are absolute (seconds on 2 cores), so they have no baseline; the ``--jobs 1`` lines
show what running side by side brings. Each line also gives the command's CPU seconds (user +
system, its worker processes included: ``getrusage(RUSAGE_CHILDREN)``), which other jobs on a
shared machine change much less than the wall time. On a loaded machine every figure is longer: say so.
Run: ``python -m benchmarks bench_tools`` (``--quick``: the small sweep grid).
"""

from __future__ import annotations

import math
import os
import re
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from benchmarks.goals import Goal, record

REPO = Path(__file__).resolve().parents[1]
SWEEP_GRID = "kp=80:140:20,kvi=600:1400:20"  #: the issue's 400 points
QUICK_GRID = "kp=80:140:2,kvi=600:1400:2"  #: 4 points over the same ranges
SWEEP_GOAL_S = 60.0
LIMIT_CYCLE_GOAL_S = 3.0
BATCH_SWEEP_GOAL_S = 30.0  #: issue 34: a 400-point sweep on 2 cores
MONTE_CARLO_GOAL_S = 600.0  #: issue 34: 10 000 samples of a 10 s hold on 2 cores
BATCH_MEMORY_GOAL_MIB = 2048.0  #: issue 34: peak memory at B = 400
MC_VARY = ["--vary", "coulomb=±20%", "--hold", "10", "--move-deg", "2", "--seed", "1"]
CALIBRATE_GOAL_S = 60.0
FIRST_TICK_GOAL_S = 3.0


def _env() -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    env.pop("VMEHIL_CALIBRATION_DIR", None)
    return env


_cpu: dict[str, float] = {}  #: CPU seconds (user + system, the command and its workers) of the last timed()


def timed(args: list[str], *, cwd: Path,
          python_flags: tuple[str, ...] = ()) -> tuple[float, subprocess.CompletedProcess]:
    """Wall seconds of ``python [flags] -m vmehil ARGS`` (it must exit 0); its CPU seconds in
    :func:`last_cpu_s` (less sensitive than the wall time to other jobs on a shared machine)."""
    cmd = [sys.executable, *python_flags, "-m", "vmehil", *args]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=cwd, env=_env(), capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    _cpu["last"] = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-2000:]}")
    return wall, proc


def last_cpu_s() -> float:
    """CPU seconds of the last :func:`timed` command (its waited-for workers included)."""
    return _cpu.get("last", math.nan)


def import_seconds(stderr: str) -> float:
    """Total of the self times in ``-X importtime`` output (s)."""
    return sum(int(m.group(1)) for m in re.finditer(r"^import time:\s+(\d+)\s*\|", stderr, re.M)) / 1e6


def main(quick: bool = False) -> list[str]:
    lines: list[str] = []
    cores = os.cpu_count() or 1

    def say(line: str) -> None:
        print(line, flush=True)
        lines.append(line)

    say(f"tools, wall time of the command in a fresh process ({cores} cores; jpl-arm, seed 0)")
    with tempfile.TemporaryDirectory(prefix="bench-tools-") as tmp:
        d = Path(tmp)
        # --- cold start -----------------------------------------------------------------------
        help_s, _ = timed(["run", "--help"], cwd=d)
        _, imp = timed(["run", "--help"], cwd=d, python_flags=("-X", "importtime"))
        timed(["run", "--duration", "0.008", "--quiet"], cwd=d)  # caches exist (bytecode, ...)
        tick_s, _ = timed(["run", "--duration", "0.008", "--quiet"], cwd=d)
        say(f"  vmehil run --help: {help_s:.2f} s, of which imports {import_seconds(imp.stderr):.2f} s")
        say(f"  vmehil run --duration 0.008 (one tick), launch to exit: {tick_s:.2f} s")
        record(Goal("vmehil run: launch to first tick (bounded by a one-tick run's launch to exit)", tick_s,
                    FIRST_TICK_GOAL_S, "s", "at_most"))
        # --- limit cycle ----------------------------------------------------------------------
        lc_s, _ = timed(["tune", "limit-cycle", "--quiet"], cwd=d)
        lc_cpu = last_cpu_s()
        lc1_s, _ = timed(["tune", "limit-cycle", "--quiet", "--jobs", "1"], cwd=d)
        say(f"  tune limit-cycle: {lc_s:.2f} s, CPU {lc_cpu:.2f} s (runs side by side, prediction beside them); "
            f"--jobs 1: {lc1_s:.2f} s, CPU {last_cpu_s():.2f} s")
        record(Goal("tune limit-cycle", lc_s, LIMIT_CYCLE_GOAL_S, "s", "at_most"))
        # --- sweep ----------------------------------------------------------------------------
        grid = QUICK_GRID if quick else SWEEP_GRID
        points = 4 if quick else 400
        sw_s, _ = timed(["tune", "sweep", "--grid", grid, "--out", str(d / "sweep"), "--quiet"], cwd=d)
        say(f"  tune sweep --grid {grid} ({points} points, {cores} workers): {sw_s:.2f} s "
            f"({sw_s / points:.2f} s per point), CPU {last_cpu_s():.1f} s")
        if quick:
            sw1_s, _ = timed(["tune", "sweep", "--grid", grid, "--jobs", "1", "--out", str(d / "sweep1"),
                              "--quiet"], cwd=d)
            say(f"  same grid, --jobs 1: {sw1_s:.2f} s")
            record(Goal(f"tune sweep, 400 points (scaled ×{400 // points} from {points} points)",
                        sw_s * 400 / points, SWEEP_GOAL_S, "s", "at_most"))
        else:
            record(Goal("tune sweep, 400 points", sw_s, SWEEP_GOAL_S, "s", "at_most"))
        # --- batched lockstep (issue 34) --------------------------------------------------------
        batch_figures(say, d, grid, points, quick)
        # --- calibration ----------------------------------------------------------------------
        cal_s, _ = timed(["calibrate", "all", "--auto", "--out", str(d / "cal.toml"), "--quiet"], cwd=d)
        say(f"  calibrate all --auto: {cal_s:.2f} s, CPU {last_cpu_s():.2f} s")
        record(Goal("calibrate all --auto", cal_s, CALIBRATE_GOAL_S, "s", "at_most"))
    return lines


def batch_figures(say: Any, d: Path, grid: str, points: int, quick: bool) -> None:
    """Issue 34's four figures, each beside its baseline of this run (module docstring)."""
    b_s, _ = timed(["tune", "sweep", "--grid", grid, "--batch", "auto", "--out", str(d / "sweepb"), "--quiet"], cwd=d)
    b_cpu = last_cpu_s()
    s_s, _ = timed(["tune", "sweep", "--grid", grid, "--batch", "1", "--out", str(d / "sweeps"), "--quiet"], cwd=d)
    say(f"  tune sweep --grid {grid} --batch auto: {b_s:.2f} s, CPU {b_cpu:.1f} s; --batch 1: {s_s:.2f} s, "
        f"CPU {last_cpu_s():.1f} s")
    scale = 400 / points
    record(Goal(f"tune sweep --batch auto, 400 points{'' if scale == 1 else f' (scaled ×{scale:g})'}", b_s * scale,
                BATCH_SWEEP_GOAL_S, "s", "at_most"))
    # lanes: one batch of 256 per worker, the size --batch auto gives a 10 000-sample study on 2 cores
    # (its 5 000 points per worker in batches of at most 256); --quick: batches of 32
    samples, size = (64, 32) if quick else (512, 256)
    scalar_samples = 8 if quick else 40
    mc = ["tune", "sweep", *MC_VARY, "--quiet"]
    mb_s, _ = timed([*mc, "--samples", str(samples), "--batch", str(size), "--out", str(d / "mcb")], cwd=d)
    mb_cpu = last_cpu_s()
    ms_s, _ = timed([*mc, "--samples", str(scalar_samples), "--batch", "1", "--out", str(d / "mcs")], cwd=d)
    say(f"  Monte Carlo, 10 s hold: --batch {size}, {samples} samples {mb_s:.2f} s (CPU {mb_cpu:.1f} s); "
        f"--batch 1, {scalar_samples} samples {ms_s:.2f} s (CPU {last_cpu_s():.1f} s) "
        f"(→ {mb_s * 10_000 / samples / 60:.1f} / {ms_s * 10_000 / scalar_samples / 60:.0f} min for 10 000)")
    record(Goal(f"Monte Carlo 10 000 samples of a 10 s hold (scaled ×{10_000 / samples:g})",
                mb_s * 10_000 / samples, MONTE_CARLO_GOAL_S, "s", "at_most"))
    b = 40 if quick else 400
    proc = subprocess.run([sys.executable, "-m", "benchmarks.bench_tools", "--peak", str(b)], cwd=REPO, env=_env(),
                          capture_output=True, text=True, check=True)
    peak, base, x_rt = (float(v) for v in proc.stdout.split())
    mem = base + (peak - base) * 400 / b
    say(f"  peak memory, B = {b} instances (10 s hold) as lanes in one process: {peak:.0f} MiB "
        f"({(peak - base) / b:.2f} MiB each over {base:.0f} MiB)"
        + ("" if b == 400 else f"; at B = 400: {mem:.0f} MiB (scaled)"))
    record(Goal(f"peak memory at B = 400{'' if b == 400 else ' (scaled ×10)'}", mem, BATCH_MEMORY_GOAL_MIB, "MiB",
                "at_most"))
    say(f"  single run (simulate, jpl-arm joint 1, 10 s hold, in-process): {x_rt:.2f}× real time (of its CPU time)")
    proc = subprocess.run([sys.executable, "-m", "benchmarks.bench_tools", "--interleave"], cwd=REPO, env=_env(),
                          capture_output=True, text=True, check=True)
    alone, w25, *lanes = (float(v) for v in proc.stdout.split())
    say(f"  CPU per instance-tick (jpl-arm, 2 s hold): alone {alone * 1e3:.0f} µs; B = 8 scalar instances in "
        f"windows of 25 ticks {w25 * 1e3:.0f} µs; as lanes: "
        + ", ".join(f"B = {b} {v * 1e3:.1f} µs" for b, v in zip(LANE_SIZES, lanes, strict=True)))


#: the batch sizes of lanes whose CPU per instance-tick ``--interleave`` prints
LANE_SIZES = (8, 50, 200)


def _peak(b: int) -> None:
    """Print the peak RSS (MiB) of this process after running ``b`` instances (10 s hold) as one rig
    of lanes to the end (their figures made), the RSS before (MiB), and one single run's × real time."""
    import time as _time

    from vmehil.analysis.lane_batch import simulate_lanes
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.simulate import SimRun, SimSettings

    jp = load_joint("jpl-arm", 1)
    sim = SimSettings(move_deg=2, hold_s=10.0)
    one = SimRun(jp, False, sim)  # warm: the kernel loaded, the DBC read
    t0 = _time.process_time()  # CPU time: other jobs on a shared machine change it less than the wall time
    with one.loop.armed():
        one.runner.run(one.n_ticks)
    x_rt = one.n_ticks * one.system.period_s / (_time.process_time() - t0)
    one.close()
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    runs = [SimRun(jp, False, sim) for _ in range(b)]
    simulate_lanes(runs)
    print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, base, x_rt)


def _interleave() -> None:
    """Print the thread CPU per instance-tick (ms) of one run alone, of a batch of 8 scalar instances
    in windows of 25 ticks, and of batches of lanes of :data:`LANE_SIZES` (jpl-arm joint 1, a 2 s hold;
    a batch's CPU includes building its instances)."""
    import time as _time

    from vmehil.analysis.batch import run_lockstep
    from vmehil.analysis.lane_batch import simulate_lanes
    from vmehil.analysis.rigparams import load_joint
    from vmehil.analysis.simulate import SimRun, SimSettings

    jp = load_joint("jpl-arm", 1)
    sim = SimSettings(move_deg=2, hold_s=2.0, allow_short=True)

    def per_tick(b: int, window: int, lanes: bool = False) -> float:
        t0 = _time.thread_time()
        runs = [SimRun(jp, False, sim) for _ in range(b)]
        ticks = b * runs[0].n_ticks
        if lanes:
            simulate_lanes(runs)
        else:
            run_lockstep(runs, window=window)
            for r in runs:
                r.close()
        return (_time.thread_time() - t0) / ticks * 1e3

    per_tick(1, 1)  # warm: the kernel loaded, the DBC read
    print(per_tick(1, 10_000), per_tick(8, 25), *(per_tick(b, 1, lanes=True) for b in LANE_SIZES))


if __name__ == "__main__":  # pragma: no cover
    if "--interleave" in sys.argv:
        _interleave()
    elif "--peak" in sys.argv:
        _peak(int(sys.argv[sys.argv.index("--peak") + 1]))
    else:
        main(quick="--quick" in sys.argv)
