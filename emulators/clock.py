"""Simulated time for the emulated crate: integer nanoseconds and a discrete-event queue.

Integer nanoseconds keep lockstep runs bit-for-bit deterministic. Boards schedule future
events (an ADC conversion finishing, a settling DAC) with :meth:`SimClock.schedule`; the
events run in time order whenever the clock advances past them.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable

NS_PER_S = 1_000_000_000
_NEVER = 1 << 126  #: "no event queued" for :attr:`SimClock.next_due_ns` (later than any time)


def seconds_to_ns(seconds: float) -> int:
    """Round a time in seconds to integer nanoseconds."""
    return round(seconds * NS_PER_S)


class SimClock:
    """Monotonic simulated clock with an event queue."""

    def __init__(self, start_ns: int = 0) -> None:
        self._now = int(start_ns)
        self._queue: list[tuple[int, int, Callable[[], None]]] = []
        self._seq = itertools.count()
        self._running = False
        #: time of the earliest queued event (a huge value when none): a bus cycle that ends
        #: before it only moves ``_now`` (see :meth:`advance_to`)
        self.next_due_ns = _NEVER
        #: while :meth:`advance_to` runs events, the time it advances to (else -1): an event
        #: callback may move the time itself up to there (:meth:`free_until`)
        self._target = -1

    @property
    def now_ns(self) -> int:
        return self._now

    @property
    def now(self) -> float:
        """Simulated time in seconds."""
        return self._now / NS_PER_S

    def schedule(self, at_ns: int, callback: Callable[[], None]) -> None:
        """Run ``callback()`` when the clock reaches ``at_ns`` (immediately-due events run at
        the next advance)."""
        at_ns = int(at_ns)
        heapq.heappush(self._queue, (at_ns, next(self._seq), callback))
        if at_ns < self.next_due_ns:
            self.next_due_ns = at_ns

    def schedule_in(self, delay_ns: int, callback: Callable[[], None]) -> None:
        self.schedule(self._now + int(delay_ns), callback)

    def advance(self, delta_ns: int) -> None:
        """Advance by ``delta_ns`` (>= 0), running due events in time order."""
        if delta_ns < 0:
            raise ValueError("simulated time cannot go backwards")
        self.advance_to(self._now + int(delta_ns))

    def advance_to(self, t_ns: int) -> None:
        """Advance to ``t_ns`` if it is later than now, running due events in order.

        The queue is looked at only when an event is due by ``t_ns`` (``next_due_ns``): most
        bus cycles end before the next event and just move the time."""
        t_ns = int(t_ns)
        if t_ns < self.next_due_ns:
            if t_ns > self._now:
                self._now = t_ns
            return
        q = self._queue
        outer, self._target = self._target, t_ns
        try:
            while q and q[0][0] <= t_ns:
                at, _, cb = heapq.heappop(q)
                if at > self._now:
                    self._now = at
                cb()
        finally:
            self._target = outer
            self.next_due_ns = q[0][0] if q else _NEVER
        if t_ns > self._now:
            self._now = t_ns

    def free_until(self, at_ns: int) -> bool:
        """Called from an event callback: True when an event scheduled now at ``at_ns`` would be
        the next to run in this :meth:`advance_to` — it ends by the time being advanced to and no
        queued event is due at or before it (an equal time queued earlier runs first). The
        callback may then set the time to ``at_ns`` and do that event's work itself: the same
        work at the same simulated instant, in the same order, without the queue."""
        q = self._queue
        return at_ns <= self._target and (not q or q[0][0] > at_ns)
    def pending(self) -> int:
        return len(self._queue)
