"""Batched lockstep: several full-stack runs stepped tick by tick together in one process.

Each instance is a complete scalar rig (:class:`vmehil.analysis.simulate.SimRun`: its own crate,
boards, drivers, harness, plant, servo loop, gains, plant values and seed); the batch ticks
instance 0, 1, …, B-1 for tick k, then every one for tick k+1. Every instance runs exactly the
calls its scalar run makes, in the same order, on objects no other instance touches, so its
recorded trajectory is the scalar run's byte for byte (tests/vmehil/analysis/test_batch.py; the
fingerprint's ``--batch`` cases). Divergence needs no handling in this form: an instance whose
drivers take an extra bus cycle (an encoder wrap-flag clear, a PWM direction flip) takes it on its
own crate and clock. docs/architecture.md, "Batched lockstep", gives the design and what the
vector-register form (one crate of B-lane registers) still needs.

Per instance: a watchdog trip safe-stops *that* instance through its own loop (its cause is in its
result) and the batch ticks the others on; an exception in an instance's tick stops that instance
(cause ``exception``), as the scalar runner does. A signal (SIGINT, SIGTERM) or ``stop()`` ends
every instance through its own safe stop (``loop.armed()``), then the batch raises the signal.

Which rigs batch: every board type built into ``emulators`` (they keep their state in the board
object). A board type from a plug-in package (entry point ``vmehil.board_types``) is not known to
keep no state shared between instances: :func:`batch_blockers` names it, ``--batch N`` refuses
such a rig in one line and ``--batch auto`` runs it scalar.
"""

from __future__ import annotations

import contextlib
import gc
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

from servo.interrupts import INTERRUPTS, SignalsDeferred, interrupt_name
from servo.rig import RigSpec
from vmehil.errors import CliError

#: resident memory one jpl-arm instance adds to a batch of lanes (MiB): 3.4 measured for a sweep point
#: of 1 469 ticks (its scalar set-up 1.4, its recorder's rows 1.2, its share of the lane rig; docs/benchmarks.md,
#: "Batched lockstep"), with a margin for longer runs
INSTANCE_MIB = 4.0
#: the most instances ``--batch auto`` puts in one batch: past a few hundred lanes a tick's fixed cost
#: (≈ 2 ms) is paid back and the memory grows on (docs/benchmarks.md, "Batched lockstep")
AUTO_MAX = 256
#: ``--batch auto`` aims at this many batches per worker (progress, and what a Ctrl-C loses)
BATCHES_PER_WORKER = 4
#: ... but no batch smaller than this while a worker has as many points: a batch of lanes costs
#: ≈ 1.8 ms a tick + ≈ 20 µs an instance (docs/benchmarks.md), 56 µs an instance-tick at 50 lanes
AUTO_MIN = 32
#: the fewest instances run as one rig of lanes: below it the lanes' fixed cost per tick (≈ 2 ms, against
#: ≈ 0.6 ms for a scalar tick) makes a batch slower than its runs one by one; smaller batches run as
#: scalar instances (docs/benchmarks.md, "Batched lockstep")
LANES_MIN = 8
#: ticks an instance runs before the next one's turn (0.2 s at 125 Hz), in a batch of scalar
#: instances: instances meet at every window's end; its own working set stays warm in the CPU's caches meanwhile
WINDOW_TICKS = 25


class BatchError(CliError):
    """A ``--batch`` that cannot be honoured (a rig that cannot batch, a bad size)."""


def batchable_types() -> frozenset[str]:
    """The board types that batch: those built into ``emulators`` (a plug-in's are not)."""
    from emulators.board_types import BUILTIN_BOARD_TYPES

    return frozenset(BUILTIN_BOARD_TYPES)


def batch_blockers(rig: RigSpec) -> list[str]:
    """The board types of ``rig``'s crate that cannot batch (not :func:`batchable_types`)."""
    ok = batchable_types()
    types = [b.get_str("type") for b in rig.table.table("crate", {}).tables("board", [])]
    return sorted({t for t in types if t not in ok})


def parse_batch(text: str) -> int | None:
    """``--batch`` value: a positive count, or ``auto`` (``None``)."""
    if text.strip().lower() == "auto":
        return None
    try:
        n = int(text)
    except ValueError:
        raise BatchError(f"--batch {text!r}: give a number of instances (1 = one run at a time) or auto") from None
    if not 1 <= n <= 100_000:
        raise BatchError(f"--batch {n}: give 1..100000 instances, or auto")
    return n


def available_mib() -> float:
    """Memory available to new work (MiB): ``MemAvailable`` of /proc/meminfo (1 GiB if unknown)."""
    with contextlib.suppress(OSError, ValueError, IndexError):
        for line in open("/proc/meminfo", encoding="ascii"):
            if line.startswith("MemAvailable:"):
                return int(line.split()[1]) / 1024.0
    return 1024.0


def choose_batch(requested: int | None, points: int, workers: int, rig: RigSpec, *,
                 memory_mib: float | None = None) -> tuple[int, str | None]:
    """The batch size for ``points`` runs over ``workers`` workers, and a note (or ``None``).

    ``requested``: ``--batch N`` (refused with :class:`BatchError` for a rig that cannot batch,
    when N > 1) or ``None`` for auto: 1 for a rig that cannot batch (the note says why), else
    :data:`BATCHES_PER_WORKER` batches per worker (so the progress bar moves and a Ctrl-C loses at
    most a quarter of a worker's points) but no smaller than :data:`AUTO_MIN` while a worker has
    that many points (below it a batch of lanes pays its fixed cost per tick for too few), at most
    :data:`AUTO_MAX` and at most what half the available memory holds at :data:`INSTANCE_MIB` per
    instance per worker. A batch of :data:`LANES_MIN` or more runs as one rig of lanes, a smaller
    one as scalar instances (:func:`simulate_batch`)."""
    blockers = batch_blockers(rig)
    if requested is not None:
        if requested > 1 and blockers:
            raise BatchError(f"--batch {requested}: rig {rig.name} has board type(s) {', '.join(blockers)} "
                             "from a plug-in, which cannot batch; use --batch 1 or --batch auto")
        return requested, None
    if blockers:
        return 1, f"--batch auto: board type(s) {', '.join(blockers)} cannot batch; running one at a time"
    mem = available_mib() if memory_mib is None else memory_mib
    by_memory = max(1, int(0.5 * mem / INSTANCE_MIB / max(1, workers)))
    per_worker = max(1, -(-points // max(1, workers)))
    size = max(-(-per_worker // BATCHES_PER_WORKER), min(AUTO_MIN, per_worker))
    return max(1, min(AUTO_MAX, by_memory, size)), None


def split(items: Sequence[Any], size: int) -> list[list[Any]]:
    """``items`` in consecutive batches of ``size`` (the last may be shorter)."""
    return [list(items[i:i + size]) for i in range(0, len(items), max(1, size))]


@dataclass
class BatchTicks:
    """What :func:`run_lockstep` did: ticks of the batch, and per instance the ticks it ran."""

    ticks: int
    per_instance: list[int]


@contextlib.contextmanager
def collector_spared() -> Iterator[Callable[[], None]]:
    """Python's cyclic garbage collector kept off a batch's runs: off while they are built; the
    caller calls the yielded ``built()`` once they are, which freezes what exists out of the
    collector's scans (``gc.freeze``) and turns it back on for the batch's ticks; at the end
    everything is unfrozen (as :meth:`servo.runner.RealtimeRunner.run` does) and collectable again.

    Why: a run's build allocates tens of thousands of objects that live as long as the batch
    (boards, the closures of resolved bus cycles, parsed parameters). With the collector on, its
    collections scan the runs built so far again and again: about half of a build (jpl-arm: 11 ms
    a run with it, 5–7 ms without), and, left unfrozen, a scan of them all later in the batch
    (≈ 1.5 ms a run). No result depends on when garbage is collected."""
    was = gc.isenabled()
    gc.disable()
    frozen = False

    def built() -> None:
        nonlocal frozen
        if not frozen:
            gc.freeze()
            frozen = True
            if was:
                gc.enable()

    try:
        yield built
    finally:
        if frozen:
            gc.unfreeze()
        elif was:
            gc.enable()


def run_lockstep(runs: Sequence[Any], *, stop: Callable[[], bool] | None = None,
                 progress: Callable[[int, int], None] | None = None, window: int = WINDOW_TICKS) -> BatchTicks:
    """Tick ``runs`` (:class:`~vmehil.analysis.simulate.SimRun`) in lockstep, each inside its own
    ``loop.armed()``, until every one has run its ticks or halted (its fault, or ``stop()``).

    The instances meet at every ``window`` ticks: each runs its next ``window`` ticks as its
    runner's ``run(window, stop=halt)`` — the scalar run's ticks with its exception handling (an
    error stops that instance), so nothing of the scalar path is copied — then the next instance.
    ``window=1`` interleaves every tick (what a vector-register batch must do); it gives the same
    numbers and costs ≈28–45 % more CPU per instance-tick here (each instance's working set is cold
    again at its next tick: docs/benchmarks.md, "Batched lockstep"). A signal that one instance's
    runner caught (it safe-stopped that instance) ends every other through its own category stop
    and is raised. ``progress(k, n)`` after each window (k: ticks of the batch so far)."""
    window = max(1, int(window))
    n = max((r.n_ticks for r in runs), default=0)
    halts = [r.halt_when(stop) for r in runs]
    live = list(range(len(runs)))
    ran = [0] * len(runs)
    k = 0
    # one section for the whole batch: the runners' own sections nest in it (no handler swaps per window)
    with contextlib.ExitStack() as stack, SignalsDeferred() as held:
        for r in runs:
            stack.enter_context(r.loop.armed())
        while live and k < n:
            still = []
            for i in live:
                r = runs[i]
                want = min(window, r.n_ticks - ran[i])
                if want <= 0:
                    continue
                done = r.runner.run(want, stop=halts[i])
                ran[i] += done
                ended = r.runner.ended_by
                signal = ended if isinstance(ended, INTERRUPTS) else held.pop(0) if held else None
                if signal is not None:
                    _stop_all(runs, signal)
                    raise signal
                if done == want and ran[i] < r.n_ticks:  # fewer: it halted (its fault, or stop())
                    still.append(i)
            live = still
            k = min(n, k + window)
            if progress is not None:
                progress(k, n)
    return BatchTicks(k, ran)


def _stop_all(runs: Sequence[Any], signal: BaseException) -> None:
    """Every instance still servoing stops as its scalar run stops on that signal (its runner's
    category stop, carried to its plant); the ``armed()`` blocks then shut every loop down."""
    for r in runs:
        loop = r.loop
        if loop.fault is None and loop.enabled and loop.stopping is None:
            loop.note_interruption(signal, "run")
            r.runner.stop_by_category("interrupted", f"{interrupt_name(signal)} received", signal)


def simulate_batch(runs: Sequence[Any], *, traces: bool = False, stop: Callable[[], bool] | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   window: int = WINDOW_TICKS, lanes: bool = True,
                   report: Any = None) -> list[dict[str, Any]]:
    """:func:`~vmehil.analysis.simulate.simulate`'s result for each of ``runs``: as one rig of
    lanes when there are at least :data:`LANES_MIN` without injected faults and they have a lane
    form (``lanes``; :func:`vmehil.analysis.lane_batch.simulate_lanes`; the faulted ones run beside
    them as scalar instances), else as scalar instances in lockstep (:func:`run_lockstep`, and
    ``report.scalar_reason`` says why). The results are the same either way, bit for bit; every run
    is closed however this ends.
    ``report``: a :class:`~vmehil.analysis.lane_batch.LaneReport` to fill (lanes, re-runs)."""
    from vmehil.analysis.lane_batch import LaneReport, simulate_lanes

    rep = report if report is not None else LaneReport(len(runs))
    # instances with injected faults have no lane form: they run as scalar instances beside the lanes
    faulted = [i for i, r in enumerate(runs) if getattr(r, "faults", ())]
    laned = [i for i in range(len(runs)) if i not in set(faulted)]
    out: list[dict[str, Any] | None] = [None] * len(runs)
    scalar = list(range(len(runs)))
    if lanes and len(laned) >= LANES_MIN:
        try:
            sub = LaneReport(len(laned))
            try:
                got = simulate_lanes([runs[i] for i in laned], traces=traces, stop=stop, progress=progress,
                                     report=sub)
            except BaseException as e:
                if not isinstance(e, NotImplementedError):  # an interruption: the faulted ones never ran
                    for i in faulted:
                        with contextlib.suppress(Exception):
                            runs[i].close()
                raise
            for i, g in zip(laned, got, strict=True):
                out[i] = g
            rep.vector_ticks = sub.vector_ticks
            rep.ejected.update({laned[b]: why for b, why in sub.ejected.items()})
            rep.ejected_tick.update({laned[b]: k for b, k in sub.ejected_tick.items()})
            scalar = faulted
            if faulted:
                rep.scalar_reason = f"{len(faulted)} instance(s) with injected faults (--fault) ran as scalar instances"
        except NotImplementedError as e:
            rep.scalar_reason = str(e)
            spent = [runs[i] for i in laned]
            fresh = list(runs)
            try:
                for i in laned:  # a board may have been taken over by the crate of lanes: from scratch
                    fresh[i] = runs[i].fresh()
            finally:
                for r in spent:
                    with contextlib.suppress(Exception):
                        r.close()
            runs = fresh
    elif faulted and lanes:
        rep.scalar_reason = f"fewer than {LANES_MIN} instances without injected faults"
    elif lanes:
        rep.scalar_reason = f"fewer than {LANES_MIN} instances"
    todo = [runs[i] for i in scalar]
    try:
        run_lockstep(todo, stop=stop, progress=progress, window=window)
        summaries = [r.summarize() for r in todo]
    finally:
        for r in todo:
            with contextlib.suppress(Exception):
                r.close()
    for i, r, sm in zip(scalar, todo, summaries, strict=True):
        out[i] = r.figures(sm, traces=traces)
    return [o for o in out if o is not None]


def cpu_workers(jobs: int | None) -> int:
    """Worker processes of a sweep: ``--jobs``, else one per core."""
    return jobs or os.cpu_count() or 1
