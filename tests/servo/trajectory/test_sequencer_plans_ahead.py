"""The sequencer plans its moves when it is made, not in the tick that starts each one."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from servo.trajectory import JointLimits, PlanContext, Quintic, Sequencer, Stay

CTX = PlanContext(JointLimits.make(2, 1.0))


@dataclass
class CountingMove:
    """A move that counts its plans: a quintic to ``target`` lasting ``duration`` s (``inf``: an
    open move, as a vservo move, holding where it started)."""

    target: tuple[float, float]
    duration: float = 1.0
    builds: list[np.ndarray] = field(default_factory=list)
    kind: str = "counting"

    def build(self, start, ctx):
        self.builds.append(np.asarray(start, float).copy())
        if math.isinf(self.duration):
            return Stay(start, math.inf)
        return Quintic(start, np.array(self.target), self.duration)


def test_every_move_is_planned_when_the_sequencer_is_made_and_none_in_a_tick() -> None:
    moves = [CountingMove((1.0, 0.0)), CountingMove((1.0, 2.0)), CountingMove((0.0, 0.0))]
    seq = Sequencer(moves, np.zeros(2), CTX)
    assert [len(m.builds) for m in moves] == [1, 1, 1]
    # each planned from the previous move's end target
    np.testing.assert_array_equal(moves[1].builds[0], [1.0, 0.0])
    np.testing.assert_array_equal(moves[2].builds[0], [1.0, 2.0])
    for t in np.arange(0.0, 4.0, 0.008):  # 125 Hz ticks through every move and past the end
        seq.sample(float(t))
    assert [len(m.builds) for m in moves] == [1, 1, 1]
    assert [r.t_start for r in seq.records] == [0.0, 1.0, 2.0] and seq.finished


def test_moves_after_an_open_move_are_planned_when_they_start() -> None:
    moves = [CountingMove((1.0, 0.0)), CountingMove((0.0, 0.0), duration=math.inf), CountingMove((0.0, 1.0))]
    Sequencer(moves, np.zeros(2), CTX)
    assert [len(m.builds) for m in moves] == [1, 1, 0]  # its start is where the open move ends


def test_a_move_that_cannot_be_planned_ahead_raises_when_it_starts() -> None:
    class Broken(CountingMove):
        def build(self, start, ctx):
            raise ValueError("no plan")

    seq = Sequencer([CountingMove((1.0, 0.0)), Broken((0.0, 0.0))], np.zeros(2), CTX)
    assert isinstance(seq.plan_error, ValueError)
    seq.sample(0.5)
    try:
        seq.sample(1.0)
    except ValueError as e:
        assert str(e) == "no plan"
    else:
        raise AssertionError("the move that cannot be planned must raise when it starts")
