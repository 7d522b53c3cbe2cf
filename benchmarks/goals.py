"""The goals a benchmark checks, each with the baseline measured in the same run.

A benchmark calls :func:`record` for every figure an issue sets a goal on; ``python -m benchmarks``
prints them all at the end in one table, and ``--check`` exits 1 when one is missed. Goals are for
people on an idle machine, never for CI: a loaded machine misses them honestly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

Kind = Literal["at_least", "at_most"]


@dataclass(frozen=True)
class Goal:
    """One figure and what it should be.

    ``measured`` and ``target`` are in ``unit``; with a ``baseline`` (same unit, same run) the
    figure judged is the ratio ``measured / baseline`` and ``target`` is that ratio's goal.
    """

    name: str
    measured: float
    target: float
    unit: str = ""
    kind: Kind = "at_least"
    baseline: float | None = None
    baseline_name: str = ""

    @property
    def judged(self) -> float:
        """The figure compared with ``target``: the ratio to the baseline when there is one."""
        if self.baseline is None:
            return self.measured
        return self.measured / self.baseline if self.baseline else math.inf

    @property
    def met(self) -> bool:
        v = self.judged
        if math.isnan(v):
            return False
        return v >= self.target if self.kind == "at_least" else v <= self.target

    def line(self) -> str:
        op = "≥" if self.kind == "at_least" else "≤"
        ok = "met " if self.met else "MISS"
        if self.baseline is None:
            fig = f"{self.measured:.4g} {self.unit}".rstrip()
            return f"{ok} {self.name}: {fig} (goal {op} {self.target:g} {self.unit})".rstrip()
        base = f"{self.baseline:.4g} {self.unit}".rstrip()
        return (f"{ok} {self.name}: {self.measured:.4g} {self.unit} vs {self.baseline_name or 'baseline'} "
                f"{base} = {self.judged:.3g}x (goal {op} {self.target:g}x)")


_recorded: list[Goal] = []


def record(goal: Goal) -> Goal:
    """Keep ``goal`` for the summary and print its line now."""
    _recorded.append(goal)
    print("  goal: " + goal.line(), flush=True)
    return goal


def recorded() -> list[Goal]:
    return list(_recorded)


def clear() -> None:
    _recorded.clear()
