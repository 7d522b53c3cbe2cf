"""Run a list of moves (quintic, LSPB, wait, …) one after the other.

Each move is a :class:`MoveSpec`: something that, given the position where it starts and the
planning context, builds a :class:`~servo.trajectory.base.Trajectory`. Each move is planned from
the previous move's end target (so plans do not depend on measurement noise), and a move ends when
its trajectory's ``duration`` has elapsed. After the last move the final target is held with
``done`` True.

Moves are planned **ahead**, when the sequencer is made (before the loop runs the first of them),
not in the tick that starts them: a plan takes time (an LSPB path of thousands of vias, tenths of a
second) that a tick does not have. Planning ahead stops at a move whose end is not known until it
has run (a ``vservo`` move: open duration) and at a move that cannot be planned now (its error is
then raised when it starts, as before); the moves after such a one are planned when they start.

Each move is checked as it is planned against the context's :class:`~servo.trajectory.bounds.MotionBounds`
(soft limits, the scene): a move they refuse raises :class:`~servo.trajectory.bounds.MotionRefused`
(kept in :attr:`Sequencer.plan_error` when planning ahead, so that the caller refuses the motion
before it starts).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, cast

import numpy as np

from servo.trajectory.base import JointLimits, Sample, Trajectory
from servo.trajectory.bounds import MotionBounds, MotionRefused
from servo.trajectory.stay import Stay


@dataclass
class PlanContext:
    """What a move may need to plan itself: joint ``limits`` and ``extras`` (e.g. a vision link for a
    visual-servo move, added by the runner under a documented key)."""

    limits: JointLimits
    extras: dict[str, Any] = field(default_factory=dict)
    #: what each planned move must stay within (soft limits, the scene); ``None``: not checked
    bounds: MotionBounds | None = None


class MoveSpec(Protocol):
    """A planned-on-start move: ``kind`` (its motion-file type) and ``build(start, ctx)``."""

    @property
    def kind(self) -> str: ...  # read-only: the moves are frozen dataclasses

    def build(self, start: np.ndarray, ctx: PlanContext) -> Trajectory: ...


@dataclass(frozen=True)
class MoveRecord:
    """When each move ran: ``index`` in the list, ``kind``, ``t_start`` s, ``duration`` s."""

    index: int
    kind: str
    t_start: float
    duration: float
    #: the trajectory the move ran (its outcome, e.g. a fine positioning's: the run report)
    trajectory: Trajectory | None = field(default=None, compare=False, repr=False)


class Sequencer:
    """Plays ``moves`` from ``start`` (rad). Call :meth:`sample` with non-decreasing ``t`` (s since
    the sequence started). ``motion_id`` increases each time a new move starts."""

    def __init__(self, moves: list[MoveSpec], start: np.ndarray, ctx: PlanContext) -> None:
        self.moves = list(moves)
        self.ctx = ctx
        self.index = -1
        self.motion_id = 0
        self.records: list[MoveRecord] = []
        self._t0 = 0.0
        self._current: Trajectory = Stay(np.asarray(start, float), 0.0)
        self._last_t = -np.inf
        self.finished = not self.moves
        #: the trajectories of moves 0, 1, … planned ahead (see the module docstring)
        self.planned: list[Trajectory] = []
        #: why planning ahead stopped before the last move (None: every move planned, or an open one)
        self.plan_error: Exception | None = None
        self._plan_ahead(np.asarray(start, float))

    def _plan_ahead(self, start: np.ndarray) -> None:
        position = start
        for i, move in enumerate(self.moves):
            try:
                trajectory = self._build(move, position, i)
            except Exception as e:  # raised again when the move starts (the loop's fault path, as before)
                self.plan_error = e
                return
            self.planned.append(trajectory)
            if not math.isfinite(trajectory.duration):  # open (vservo): its end is not known yet
                return
            position = trajectory.end

    def _build(self, move: MoveSpec, start: np.ndarray, index: int) -> Trajectory:
        """Plan ``move`` from ``start`` and check it against the context's bounds
        (:class:`MotionRefused` for a move they refuse, before it starts)."""
        try:
            trajectory = move.build(start, self.ctx)
        except MotionRefused as e:  # refused by the move itself (a Cartesian target out of reach): name the move
            raise MotionRefused([replace(r, move=index, detail=f"move {index + 1}: {r.detail}") if r.move is None
                                 else r for r in e.refusals]) from None
        bounds = self.ctx.bounds
        if bounds is not None:
            refusals = bounds.check_trajectory(trajectory, move=index)
            if refusals:
                raise MotionRefused(refusals)
        return trajectory

    @property
    def current(self) -> Trajectory:
        return self._current

    def _advance(self, t_start: float) -> None:
        start = self._current.end
        self.index += 1
        if self.index >= len(self.moves):
            self._current = Stay(start)
            self.finished = True
            return
        move = self.moves[self.index]
        planned = self.planned[self.index] if self.index < len(self.planned) else None
        if planned is not None and not np.array_equal(np.asarray(planned.start, float), start):
            planned = None  # the move before ended elsewhere than planned (a fine positioning's trim)
        self._current = planned if planned is not None else self._build(move, start, self.index)
        self._t0 = t_start
        self.motion_id += 1
        self.records.append(MoveRecord(self.index, move.kind, t_start, float(self._current.duration), self._current))

    def sample(self, t: float) -> Sample:
        if t < self._last_t:
            raise ValueError(f"sequencer time went backwards: {t!r} < {self._last_t!r}")
        self._last_t = t
        if self.index < 0 and self.moves:
            self._advance(0.0)
        # zero-length moves are skipped at once; a move ends when its duration has elapsed
        while not self.finished and t - self._t0 >= self._current.duration:
            self._advance(self._t0 + self._current.duration)
        return self._current.sample(t - self._t0)

    @property
    def total_duration(self) -> float | None:
        """Sum of the durations of the moves planned so far, or None before all are planned."""
        if not self.finished:
            return None
        return float(sum(r.duration for r in self.records))


class LaneSequencer:
    """B sequencers played together (batched lockstep, :mod:`hal.lanes`): :meth:`sample` gives
    the B samples as one, lane-major (joint j of lane b at ``b*n + j``; ``done`` per joint).

    Each lane keeps its own :class:`Sequencer` (its moves, records and plans: what the run report
    reads). A sample is cheap where it can be: while every lane holds a :class:`Stay` that does not
    end before ``t`` (a hold, a step's target, a wait), the sample is the one already stacked; while
    every lane plays a :class:`~servo.trajectory.quintic.Quintic`, it is computed for all lanes at
    once with the scalar expressions (the same operations, elementwise: bit for bit). Otherwise, and
    on every tick where some lane's move ends, each lane's sequencer samples on its own."""

    def __init__(self, sequencers: Sequence[Sequencer]) -> None:
        from servo.trajectory.quintic import Quintic

        self._quintic_type = Quintic
        first = sequencers[0]
        self.lanes = list(sequencers)
        self.n = int(np.asarray(first.current.end).shape[0])
        self.size = len(self.lanes)
        for s in self.lanes:
            if s.plan_error is not None or len(s.planned) < len(s.moves):
                raise NotImplementedError("a motion not planned ahead (an open or refused move) cannot run in lanes")
            if any(getattr(m, "kind", "") == "hand" for m in s.moves):
                raise NotImplementedError("a hand move (the hand by current) cannot run in lanes")
        #: the plan context of lane 0 (the loop offers its measurement there; lanes never re-plan)
        self.ctx = first.ctx
        self._mode = ""  # "stay" / "quintic": what the stacked arrays below hold, "" none
        self._t0 = np.zeros(self.size)
        self._dur = np.zeros(self.size)
        self._open = np.zeros(self.size, bool)

    @property
    def current(self) -> Any:
        return self.lanes[0].current

    @property
    def finished(self) -> bool:
        return all(s.finished for s in self.lanes)

    def sample(self, t: float) -> Sample:
        mode = self._mode
        # a lane's move ends where its sequencer would advance: t - t0 >= duration (the same test)
        if mode and not np.any(self._open & (t - self._t0 >= self._dur)):
            return self._sample_stay(t) if mode == "stay" else self._sample_quintic(t)
        samples = [s.sample(t) for s in self.lanes]
        n = self.n
        theta = np.concatenate([np.asarray(x.theta_d, float) for x in samples])
        omega = np.concatenate([np.asarray(x.omega_d, float) for x in samples])
        alpha = np.concatenate([np.broadcast_to(np.asarray(x.alpha_d, float), (n,)) for x in samples])
        done = np.repeat(np.array([bool(x.done) for x in samples]), n)
        self._restack()
        return Sample(theta, omega, alpha, cast(bool, done))  # per joint in lanes (ControlContext takes either)

    def _restack(self) -> None:
        """After the lanes' sequencers moved on: which fast path holds until some lane's move ends."""
        lanes = self.lanes
        currents = [s.current for s in lanes]
        self._t0 = np.array([s._t0 for s in lanes])
        self._dur = np.array([float(c.duration) for c in currents])
        self._open = np.array([not s.finished for s in lanes])
        self._mode = ""
        if all(type(c) is Stay for c in currents):
            self._theta = np.concatenate([c.start for c in currents])
            self._zeros = np.zeros(self._theta.shape)
            self._done = np.ones(self._theta.shape, bool)
            self._mode = "stay"
        elif all(type(c) is self._quintic_type for c in currents) and all(
                c.duration >= 1e-9 for c in currents):  # (shorter: a step, sampled by the lanes)
            n = self.n
            self._q_start = np.concatenate([c.start for c in currents])
            self._q_delta = np.concatenate([cast(Any, c).delta for c in currents])
            self._done = np.zeros(self._q_start.shape, bool)
            self._q_n = n
            self._mode = "quintic"

    def _sample_stay(self, t: float) -> Sample:
        """:meth:`Stay.sample` of every lane at once."""
        return Sample(self._theta.copy(), self._zeros.copy(), self._zeros.copy(), cast(bool, self._done.copy()))

    def _sample_quintic(self, t: float) -> Sample:
        """:meth:`Quintic.sample` of every lane at once (t < duration in every lane here)."""
        T = self._dur
        tr = t - self._t0
        u = np.where(0.0 > tr, 0.0, tr) / T  # max(t, 0.0): t unless 0.0 is greater
        u2 = u * u
        p = u2 * u * (10.0 - 15.0 * u + 6.0 * u2)
        v = 30.0 * u2 * (1.0 - 2.0 * u + u2)
        a = 60.0 * u * (1.0 - 3.0 * u + 2.0 * u2)
        n = self._q_n
        return Sample(self._q_start + self._q_delta * np.repeat(p, n), self._q_delta * np.repeat(v / T, n),
                      self._q_delta * np.repeat(a / (T * T), n), cast(bool, self._done.copy()))
