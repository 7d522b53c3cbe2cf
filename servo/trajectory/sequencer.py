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
from dataclasses import dataclass, field, replace
from typing import Any, Protocol

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
