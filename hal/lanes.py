"""Lanes: B independent instances of a rig in one set of objects (batched lockstep, issue #34).

A lane-mode object (a crate, a board, a driver, the harness, the plant, the servo loop) holds
the state of B instances that execute the same program tick by tick. Every value that can
differ between instances is a numpy array with a trailing *lane axis* of length B (a register or
a net: shape ``(B,)``); a value every lane holds alike stays a plain Python ``int``/``float``/
``bool``. With B = 1 nothing is a lane array: the scalar path is the code as it was.

The program is the same in every lane: where code must branch on a value that may differ per
lane, it asks :meth:`LaneSet.decide` (or ``VmeBus.decide``), which returns the branch of the
majority of the live lanes and *ejects* the lanes that would have taken the other one. An
ejected lane is no longer followed: its values go on being computed (and are garbage from then
on); the batch runs that instance again on its own (the scalar path) and reports that run. Where
the scalar program would raise or stop for a lane (a NaN at the ADC, a value out of range on the
bus, a watchdog trip), lane code calls :meth:`LaneSet.eject` for those lanes and goes on with
the others. So every lane still live at the end made exactly the calls, in the same order, with
the same values and at the same simulated times as its scalar run: its results are the scalar
run's, bit for bit (docs/architecture.md, "Batched lockstep").

Lane-mode objects are built by stacking B scalar objects built exactly as a scalar run builds
them (``from_lanes`` class methods, :func:`stack`): the set-up of each instance is its own scalar
set-up, and the batch takes over at the first tick.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

LaneValue = Any
"""A value per lane: a Python scalar (every lane alike) or an array with a trailing lane axis."""


class LaneSet:
    """The B lanes of a batch, which of them are still followed, and why the others were left."""

    __slots__ = ("alive", "first_tick", "reasons", "size", "tick")

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"a batch needs at least one lane, got {size}")
        self.size = int(size)
        self.alive = np.ones(self.size, dtype=bool)
        #: why each ejected lane was left (the first reason given for it)
        self.reasons: dict[int, str] = {}
        #: the tick at which each ejected lane was left (``tick`` when it was ejected)
        self.first_tick: dict[int, int] = {}
        #: the current tick (the batch runner sets it; only for the record of ejections)
        self.tick = 0

    @property
    def n_alive(self) -> int:
        return int(self.alive.sum())

    def eject(self, mask: Any, reason: str) -> None:
        """Stop following the live lanes where ``mask`` is true (a bool array of shape (B,), or a
        Python bool for every lane): their scalar runs would do something the others do not."""
        if type(mask) is np.ndarray and mask.dtype == np.bool_ and mask.shape == (self.size,):
            m = mask & self.alive  # the usual mask: no broadcast (a tick ejects nothing ~10 times)
        else:
            m = np.broadcast_to(np.asarray(mask, dtype=bool), (self.size,)) & self.alive
        if not np.count_nonzero(m):  # count_nonzero: a third of .any()'s cost on (B,) bools
            return
        for b in np.flatnonzero(m).tolist():
            self.reasons.setdefault(b, reason)
            self.first_tick.setdefault(b, self.tick)
        self.alive = self.alive & ~m

    def decide(self, cond: Any, reason: str) -> bool:
        """The branch the live lanes take on ``cond`` (a scalar or a (B,) array of truth values):
        their common answer; when they differ, the answer of the majority (ties: ``True``), and
        the lanes of the other answer are ejected with ``reason``."""
        if not isinstance(cond, np.ndarray):
            return bool(cond)
        c = np.asarray(cond, dtype=bool)
        if c.shape != (self.size,):
            raise ValueError(f"a lane condition has shape (B,) = ({self.size},), got {c.shape}")
        alive = self.alive
        n_true = int((c & alive).sum())
        n_alive = int(alive.sum())
        if n_true == n_alive:
            return True
        if n_true == 0:
            return False
        answer = 2 * n_true >= n_alive
        self.eject(c != answer, reason)
        return answer

    def any(self, cond: Any) -> bool:
        """True when ``cond`` holds in any live lane (a scalar: itself)."""
        if not isinstance(cond, np.ndarray):
            return bool(cond)
        return bool(np.count_nonzero(np.asarray(cond, dtype=bool) & self.alive))


def stack(values: Sequence[Any]) -> Any:
    """One lane value from B scalar values (one per lane, in lane order): the value itself when
    every lane holds the same (same type and equal; arrays: same shape and equal elementwise,
    NaN equal to NaN), else an array with the lane axis last."""
    first = values[0]
    if isinstance(first, np.ndarray):
        arrays = [np.asarray(v) for v in values]
        nan_equal = first.dtype.kind in "fc"
        if all(a.shape == first.shape and a.dtype == first.dtype and np.array_equal(a, first, equal_nan=nan_equal)
               for a in arrays[1:]):
            return first
        return np.stack(arrays, axis=-1)
    if all(type(v) is type(first) and (v == first or (v != v and first != first)) for v in values[1:]):
        return first
    return np.array(values)


def lane(value: Any, b: int) -> Any:
    """Lane ``b``'s value of a lane value (a scalar is every lane's)."""
    if isinstance(value, np.ndarray):
        return value[..., b]
    return value
