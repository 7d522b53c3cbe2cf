"""VME interrupt arbitration: IRQ1–7 by priority, daisy chain by slot, status/ID on IACK.

The crate's interrupt handler (the 68020's view) services the highest pending level above
the current interrupt priority level (IPL). Within a level, the board nearest slot 1 wins
the IACK daisy chain. A ROAK board releases its line on IACK; a RORA board keeps it asserted
until its handler touches the board's registers, so a handler that forgets to clear the
source is re-entered (an interrupt storm, counted and cut after ``storm_limit`` dispatches).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Protocol


class InterruptSource(Protocol):
    """What the arbiter needs of a board (:class:`emulators.board.Board`): its slot and name
    for the daisy chain, and its answer to IACK. A protocol, so that this module does not import
    the boards, which assert lines through it."""

    name: str
    slot: int

    def iack(self, level: int) -> int: ...


class IrqController:
    """Interrupt lines of one crate."""

    def __init__(
        self,
        lookup: Callable[[int], Callable[[int], None] | None],
        on_iack: Callable[[int, int], None] | None = None,
        storm_limit: int = 64,
    ) -> None:
        self._lookup = lookup
        self._on_iack = on_iack
        self._asserted: dict[int, set[InterruptSource]] = {level: set() for level in range(1, 8)}
        self.ipl = 0  #: current interrupt priority level (handlers at or below it wait)
        self.storm_limit = storm_limit
        self.unhandled: list[int] = []  #: vectors that had no handler
        self.storms = 0
        #: the highest asserted level (0: none), kept by assert/release: the crate calls
        #: :meth:`service` after a cycle only when this is above the IPL
        self.highest = 0

    def assert_line(self, board: InterruptSource, level: int) -> None:
        for boards in self._asserted.values():
            boards.discard(board)
        self._asserted[level].add(board)
        self.highest = self.highest_pending()

    def release_line(self, board: InterruptSource) -> None:
        for boards in self._asserted.values():
            boards.discard(board)
        self.highest = self.highest_pending()

    def pending_levels(self) -> list[int]:
        return [lvl for lvl in range(7, 0, -1) if self._asserted[lvl]]

    def highest_pending(self) -> int:
        for lvl in range(7, 0, -1):
            if self._asserted[lvl]:
                return lvl
        return 0

    def service(self) -> int:
        """Dispatch pending interrupts above the IPL; returns how many handlers ran."""
        ran = 0
        while True:
            level = self.highest_pending()
            if level <= self.ipl:
                return ran
            if ran >= self.storm_limit:
                self.storms += 1
                return ran
            board = min(self._asserted[level], key=lambda b: (b.slot, b.name))
            vector = board.iack(level)
            if self._on_iack is not None:
                self._on_iack(level, vector)
            handler = self._lookup(vector)
            ran += 1
            if handler is None:
                self.unhandled.append(vector)
                # An unhandled RORA source would storm forever; a real CPU takes the
                # uninitialized-vector exception. We drop the request and record it.
                self.release_line(board)
                continue
            saved, self.ipl = self.ipl, level
            try:
                handler(vector)
            finally:
                self.ipl = saved
