"""The emulated VME crate: address decoding, bus timing, BERR, interrupts and counters.

A :class:`Crate` *is* a :class:`hal.vme.VmeBus`, so drivers cannot tell it from hardware.
Every cycle advances the simulated clock by the board's cycle time (or by the bus timeout
when nobody answers), runs due board events, then services pending interrupts — like a CPU
that takes interrupts between instructions.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass
from typing import Any

from emulators.board import Board, BoardAccessError
from emulators.clock import SimClock, seconds_to_ns
from emulators.irq import IrqController
from emulators.signals import Signals
from hal.vme.bus import VmeBus
from hal.vme.errors import BusError, BusErrorCause, VmeConfigError
from hal.vme.types import AddressModifier, AddressSpace, Width

DEFAULT_BUS_TIMEOUT_NS = 64_000  #: VMEbus BTO(64): the usual system-controller timer


@dataclass(frozen=True)
class Slot:
    board: Board
    space: AddressSpace
    base: int
    end: int  # exclusive


class Crate(VmeBus):
    """An emulated VME crate.

    Args:
        name: crate name (for messages).
        bus_timeout_ns: time a cycle that nobody acknowledges takes before BERR.
        clock: a shared :class:`SimClock` (a new one by default).
        signals: the connector-panel nets the boards are wired to.
    """

    def __init__(
        self,
        name: str = "crate",
        *,
        bus_timeout_ns: int = DEFAULT_BUS_TIMEOUT_NS,
        clock: SimClock | None = None,
        signals: Signals | None = None,
    ) -> None:
        super().__init__()
        self.name = name
        self.bus_timeout_ns = int(bus_timeout_ns)
        self.clock = clock or SimClock()
        self.signals = signals or Signals()
        self._slots: list[Slot] = []
        self.boards: dict[str, Board] = {}
        self.counters: Counter[str] = Counter()
        # hot-path caches (a servo tick makes ~100 cycles): counter key per (write, AM, width),
        # decoded slot per (AM, address, width); cleared when a board is installed
        self._counter_keys: dict[tuple[bool, int, Width], str] = {}
        self._decode_cache: dict[tuple[int, int, Width], Slot] = {}
        self.irq = IrqController(self.irq_handler, on_iack=self._count_iack)

    # --- configuration -------------------------------------------------------------------
    def install(self, board: Board, *, base: int, space: AddressSpace | str, slot: int | None = None) -> Board:
        """Put ``board`` in the crate at ``base`` in ``space``.

        Raises :class:`VmeConfigError` when the name is taken, the window leaves the space or
        overlaps another board's window (the message names both boards).
        """
        space = AddressSpace.parse(space)
        if board.name in self.boards:
            raise VmeConfigError(f"crate {self.name}: a board named {board.name!r} is already installed")
        end = base + board.size
        if base < 0 or end > space.size:
            raise VmeConfigError(
                f"crate {self.name}: board {board.name!r} window 0x{base:X}..0x{end - 1:X} does not fit {space.name}"
            )
        if base % 2:
            raise VmeConfigError(f"crate {self.name}: board {board.name!r} base 0x{base:X} must be even")
        for s in self._slots:
            if s.space is space and base < s.end and s.base < end:
                raise VmeConfigError(
                    f"crate {self.name}: board {board.name!r} ({space.name} 0x{base:X}..0x{end - 1:X}) "
                    f"overlaps board {s.board.name!r} ({space.name} 0x{s.base:X}..0x{s.end - 1:X})"
                )
        if slot is None:
            slot = len(self._slots) + 2  # slot 1 is the CPU / system controller
        if not 1 <= slot <= 21:
            raise VmeConfigError(f"crate {self.name}: board {board.name!r} slot {slot} is not 1..21")
        board.base, board.space, board.slot = base, space, slot
        self._slots.append(Slot(board, space, base, end))
        self._decode_cache.clear()
        self.boards[board.name] = board
        board.attach(self)
        return board

    def board(self, name: str) -> Board:
        try:
            return self.boards[name]
        except KeyError:
            known = ", ".join(self.boards) or "none"
            raise KeyError(f"crate {self.name} has no board {name!r} (boards: {known})") from None

    def slots(self) -> list[Slot]:
        return sorted(self._slots, key=lambda s: (s.board.slot, s.base))

    # --- VmeBus --------------------------------------------------------------------------
    def now(self) -> float:
        return self.clock.now

    def delay(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("delay must be >= 0")
        self.clock.advance(seconds_to_ns(seconds))
        self.irq.service()

    def advance_to(self, t_ns: int) -> None:
        """Jump simulated time forward (runners align the crate to tick boundaries)."""
        self.clock.advance_to(t_ns)
        self.irq.service()

    def _decode(self, am: AddressModifier, address: int, width: Width) -> Slot | None:
        for s in self._slots:
            if s.space is am.space and s.base <= address < s.end:
                if address + int(width) > s.end:
                    return None
                return s
        return None

    def _cycle(self, am: AddressModifier, address: int, width: Width, value: int | None) -> int:
        write = value is not None
        ck = (write, am.code, width)
        key = self._counter_keys.get(ck)
        if key is None:
            key = self._counter_keys[ck] = f"{'write' if write else 'read'}.{am.space.name}.{width.name}"
        self.counters[key] += 1
        dk = (am.code, address, width)
        s = self._decode_cache.get(dk)
        if s is None:
            s = self._decode(am, address, width)
            if s is not None:
                if len(self._decode_cache) >= 4096:  # e.g. a large memory board swept once
                    self._decode_cache.clear()
                self._decode_cache[dk] = s
        if s is None or s.board.removed:  # a pulled board decodes nothing: the bus timer ends the cycle
            self.clock.advance(self.bus_timeout_ns)
            self.counters[f"error.{BusErrorCause.NO_RESPONDER.name}"] += 1
            self.irq.service()
            raise BusError(address, am, width, BusErrorCause.NO_RESPONDER, write=write)
        board = s.board
        self.clock.advance(board.cycle_ns(width, am.block))
        try:
            if write:
                board.bus_write(address - s.base, width, value)  # type: ignore[arg-type]
                result = 0
            else:
                result = board.bus_read(address - s.base, width)
        except BoardAccessError as e:
            self.counters[f"error.{e.cause.name}"] += 1
            self.irq.service()
            raise BusError(address, am, width, e.cause, e.detail, write=write) from None
        self.irq.service()
        return result

    def _read(self, am: AddressModifier, address: int, width: Width) -> int:
        return self._cycle(am, address, width, None)

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        self._cycle(am, address, width, value)

    def _count_iack(self, level: int, vector: int) -> None:
        self.counters[f"iack.IRQ{level}"] += 1
        self.clock.advance(300)

    # --- reports -------------------------------------------------------------------------
    def counter_snapshot(self) -> dict[str, int]:
        """Access counters: ``read.A24.D16``, ``write.A16.D8``, ``error.NO_RESPONDER``, ``iack.IRQ3``."""
        snap = dict(sorted(self.counters.items()))
        snap["irq.unhandled"] = len(self.irq.unhandled)
        snap["irq.storms"] = self.irq.storms
        return snap

    def describe(self) -> list[dict[str, Any]]:
        rows = []
        for s in self.slots():
            row = {
                "slot": s.board.slot,
                "name": s.board.name,
                "space": s.space.name,
                "base": f"0x{s.base:X}",
                "end": f"0x{s.end - 1:X}",
            }
            row.update(s.board.describe())
            rows.append(row)
        return rows

    def reset(self) -> None:
        """SYSRESET: every board returns to its power-up state."""
        for b in self.boards.values():
            b.reset()
