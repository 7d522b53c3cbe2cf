"""The vector form of a batch: B runs as one rig of lanes (issue #34; hal.lanes).

:func:`simulate_lanes` builds each :class:`~vmehil.analysis.simulate.SimRun` as a scalar run
builds it, stacks the B rigs and servo loops into one of lanes (:func:`vmehil.rig_setup.lane_rig.stack_rigs`,
``ServoLoop.from_lanes``) and ticks that one: one bus program, one plant call, one controller
update per tick for every instance. A lane whose scalar run would have done something the
others did not (a watchdog trip, an encoder wrap-flag clear, an error) is left at that tick
(:meth:`hal.lanes.LaneSet.eject`) and run again on its own afterwards; every lane followed to
the end has its scalar run's results bit for bit, so every instance's figures are its scalar
run's (docs/architecture.md, "Batched lockstep").
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from hal.lanes import LaneSet
from servo.interrupts import INTERRUPTS


@dataclass
class LaneReport:
    """What the lanes did: how many, which were left (lane → reason, tick) and run again alone."""

    size: int
    ejected: dict[int, str] = field(default_factory=dict)
    ejected_tick: dict[int, int] = field(default_factory=dict)
    vector_ticks: int = 0
    #: why the batch ran as scalar instances instead (``None``: it ran as lanes)
    scalar_reason: str | None = None

    def as_dict(self) -> dict[str, Any]:
        return {"lanes": self.size, "vector_ticks": self.vector_ticks, "scalar_reason": self.scalar_reason,
                "rerun": {str(b): {"reason": r, "tick": self.ejected_tick.get(b)} for b, r in self.ejected.items()}}


def stack_runs(runs: Sequence[Any], lanes: LaneSet) -> tuple[Any, Any, Any]:
    """The lane rig, servo loop and runner of ``runs`` (built, not yet ticked), or
    :class:`NotImplementedError` saying why they have no lane form."""
    from servo.loop import ServoLoop
    from servo.runner import LockstepRunner
    from vmehil.rig_setup.lane_rig import stack_rigs

    r0 = runs[0]
    for r in runs:
        if r.n_ticks != r0.n_ticks:
            raise NotImplementedError("the instances run for different numbers of ticks")
        if r.faults:
            raise NotImplementedError("an instance has injected faults (--fault)")
        if r.runner.after_tick:
            raise NotImplementedError("an instance has per-tick hooks")
    rig = stack_rigs([r.system for r in runs], lanes)
    loop = ServoLoop.from_lanes([r.loop for r in runs], io=rig.io, lanes=lanes)
    runner = LockstepRunner.from_lanes([r.runner for r in runs], plant=rig, loop=loop)
    return rig, loop, runner


def simulate_lanes(runs: Sequence[Any], *, traces: bool = False, stop: Callable[[], bool] | None = None,
                   progress: Callable[[int, int], None] | None = None,
                   report: LaneReport | None = None) -> list[dict[str, Any]]:
    """:func:`~vmehil.analysis.simulate.simulate`'s result for each of ``runs`` (built
    :class:`~vmehil.analysis.simulate.SimRun` s, not yet ticked), run as one rig of lanes.
    Raises :class:`NotImplementedError` before any tick when they have no lane form (the caller
    then runs them as scalar instances: :func:`vmehil.analysis.batch.simulate_batch`); the runs
    are spent either way (a board may have been taken over: run ``fresh()`` copies)."""
    lanes = LaneSet(len(runs))
    _rig, loop, runner = stack_runs(runs, lanes)
    try:
        return _tick_lanes(runs, lanes, loop, runner, traces=traces, stop=stop, progress=progress,
                           report=report)
    finally:
        for r in runs:
            with contextlib.suppress(Exception):
                r.close()


def _tick_lanes(runs: Sequence[Any], lanes: LaneSet, loop: Any, runner: Any, *, traces: bool,
                stop: Callable[[], bool] | None, progress: Callable[[int, int], None] | None,
                report: LaneReport | None) -> list[dict[str, Any]]:
    n = runs[0].n_ticks

    def tick_done(_loop: Any) -> None:
        lanes.tick = _loop.tick_count

    runner.after_tick.append(tick_done)

    def halt() -> bool:
        return lanes.n_alive == 0 or (stop is not None and stop())

    with loop.armed():
        runner.run(n, progress=progress, stop=halt)
    if isinstance(runner.ended_by, INTERRUPTS):
        raise runner.ended_by
    rep = report if report is not None else LaneReport(len(runs))
    rep.vector_ticks = loop.tick_count
    out: list[dict[str, Any] | None] = [None] * len(runs)
    for b, r in enumerate(runs):
        if lanes.alive[b] and loop.fault is None:
            loop.write_lane(b, r.loop)
            out[b] = r.figures(r.summarize(), traces=traces)
            r.loop.recorder = None  # its rows are in out[b]; the batch's memory is the lane recorder's
    for b in range(len(runs)):
        if out[b] is not None:
            continue
        rep.ejected[b] = lanes.reasons.get(b, loop.fault.cause if loop.fault is not None else "stopped")
        rep.ejected_tick[b] = lanes.first_tick.get(b, lanes.tick)
        # on its own from the start: its scalar run (a sweep's stop() halts it at once, as it
        # halts every instance of a scalar batch at its next tick)
        out[b] = _run_alone(runs[b].fresh(), traces=traces, stop=stop)
    return [o for o in out if o is not None]


def _run_alone(run: Any, *, traces: bool, stop: Callable[[], bool] | None) -> dict[str, Any]:
    """One instance on its own, as :func:`~vmehil.analysis.simulate.simulate` runs it."""
    try:
        with run.loop.armed():
            run.runner.run(run.n_ticks, stop=run.halt_when(stop))
        summary = run.summarize()
    finally:
        with contextlib.suppress(Exception):
            run.close()
    return run.figures(summary, traces=traces)  # type: ignore[no-any-return]
