"""The emulated VME crate: address decoding, bus timing, BERR, interrupts and counters.

A :class:`Crate` *is* a :class:`hal.vme.VmeBus`, so drivers cannot tell it from hardware.
Every cycle advances the simulated clock by the board's cycle time (or by the bus timeout
when nobody answers), runs due board events, then services pending interrupts — like a CPU
that takes interrupts between instructions.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np

from emulators.board import Board, BoardAccessError
from emulators.clock import SimClock, seconds_to_ns
from emulators.irq import IrqController
from emulators.signals import Signals
from hal.lanes import LaneSet
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BusError, BusErrorCause, VmeConfigError
from hal.vme.types import AddressModifier, AddressSpace, VmeValueError, Width

DEFAULT_BUS_TIMEOUT_NS = 64_000  #: VMEbus BTO(64): the usual system-controller timer

#: An observer of every bus cycle (a trace: vmehil.scope), called once the cycle has ended:
#: ``(t_ns, am, address, width, write, value, error)`` -- the simulated time at its end, what the
#: driver asked, the value read or written (0 for a cycle that ended in BERR) and whether it did.
CycleTap = Callable[[int, AddressModifier, int, Width, bool, int, bool], None]


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
        # hot-path caches (a servo tick makes ~60-130 cycles): counter key per (write, AM code,
        # width); resolved cycles per (AM, address, width, write) and per the arguments of
        # read()/write(); forgotten when a board is installed (see _resolve_cycle)
        self._counter_keys: dict[tuple[bool, int, Width], str] = {}
        self._cycles: dict[tuple[AddressModifier, int, Width, bool], Any] = {}
        self._reads: dict[tuple[int, Any, Width], Callable[[], int]] = {}
        self._writes: dict[tuple[int, Any, Width], Callable[[int], None]] = {}
        self._blocks: dict[tuple[int, int, Any, Width], tuple[Callable[[], int], ...]] = {}
        self._generation = 0
        self._tap: CycleTap | None = None
        self.irq = IrqController(self.irq_handler, on_iack=self._count_iack)

    # --- lanes (batched lockstep: hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, crates: Sequence[Crate], lanes: LaneSet) -> Crate:
        """One crate of ``lanes`` holding B scalar crates built alike (lane order): their boards
        stacked (each board type's ``from_lanes``, installed where it was), their nets stacked
        (:meth:`Signals.from_lanes`), their common time. The B crates must be at the same point of
        the same program: the same layout, time, counters, no event queued, no interrupt pending
        or handled, no trace tap (:class:`NotImplementedError` names what differs). The B crates
        are not used afterwards (a board may be taken over as it is: ``Board._adopt_passive``)."""
        c0 = crates[0]
        if len(crates) != lanes.size:
            raise ValueError(f"{len(crates)} crates for {lanes.size} lanes")
        layout = [(s.board.name, s.space, s.base, s.board.slot) for s in c0._slots]
        for c in crates:
            if [(s.board.name, s.space, s.base, s.board.slot) for s in c._slots] != layout:
                raise NotImplementedError(f"crate {c.name}: the instances' crates differ in their boards")
            if c.clock.now_ns != c0.clock.now_ns or c.clock.pending():
                raise NotImplementedError(f"crate {c.name}: the instances are at different times or have events queued")
            if c.counters != c0.counters:
                raise NotImplementedError(f"crate {c.name}: the instances made different bus cycles in their set-up")
            if c.irq.highest or c.irq.ipl or c._irq_handlers or c._tap is not None:
                raise NotImplementedError(f"crate {c.name}: interrupts or a cycle trace in use: no lane form")
        crate = cls(c0.name, bus_timeout_ns=c0.bus_timeout_ns, clock=SimClock(c0.clock.now_ns),
                    signals=Signals.from_lanes([c.signals for c in crates]))
        crate.lanes = lanes
        crate.counters.update(c0.counters)
        for name, space, base, slot in layout:
            if name in crate.boards:
                continue  # installed by another board's attach (a BIT3 card's window)
            board = type(c0.boards[name]).from_lanes([c.boards[name] for c in crates], crate)
            crate.install(board, base=base, space=space, slot=slot)
        return crate

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
        self.invalidate()
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
        if self.irq.highest > self.irq.ipl:
            self.irq.service()

    def advance_to(self, t_ns: int) -> None:
        """Jump simulated time forward (runners align the crate to tick boundaries)."""
        self.clock.advance_to(t_ns)
        if self.irq.highest > self.irq.ipl:
            self.irq.service()

    def _decode(self, am: AddressModifier, address: int, width: Width) -> Slot | None:
        for s in self._slots:
            if s.space is am.space and s.base <= address < s.end:
                if address + int(width) > s.end:
                    return None
                return s
        return None

    # --- cycles, resolved once per (space, address, width) -------------------------------
    # A servo tick makes ~60-130 cycles to the same few dozen registers. The first cycle to an
    # address resolves everything that does not change between cycles there: the VmeBus
    # checks, the counter key, the board decoding it, the board's cycle time and the board's
    # dispatch on its register map (Board.reader/writer). The resolved cycle then does only
    # what each cycle must: count, check the board is still in the crate, advance the clock
    # (events only when due), call the board, service interrupts when a line is up. Installing
    # a board bumps the layout generation: every resolved cycle decodes again.
    def read(self, address: int, *, space: SpaceLike = AddressSpace.A16, width: Width = Width.D16) -> int:
        c = self._reads.get((address, space, width)) if type(width) is Width else None
        if c is None:
            c = self.reader(address, space=space, width=width)
        return c()

    def write(self, address: int, value: int, *, space: SpaceLike = AddressSpace.A16,
              width: Width = Width.D16) -> None:
        c = self._writes.get((address, space, width)) if type(width) is Width else None
        if c is None:
            c = self.writer(address, space=space, width=width)
        c(value)

    def reader(self, address: int, *, space: SpaceLike = AddressSpace.A16,
               width: Width = Width.D16) -> Callable[[], int]:
        am, w = self._check(address, space, width, write=False)
        c = self._cycle_for(am, address, w, False)
        if type(width) is Width:
            self._remember(self._reads, (address, space, width), c)
        return c

    def writer(self, address: int, *, space: SpaceLike = AddressSpace.A16,
               width: Width = Width.D16) -> Callable[[int], None]:
        am, w = self._check(address, space, width, write=True)
        if self.lanes is not None:
            c = partial(_checked_lane_value, self._cycle_for(am, address, w, True), w, w.max_value, self.lanes)
        else:
            c = partial(_checked_value, self._cycle_for(am, address, w, True), w, w.max_value)
        if type(width) is Width:
            self._remember(self._writes, (address, space, width), c)
        return c

    def read_block(self, address: int, count: int, *, space: SpaceLike = AddressSpace.A24,
                   width: Width = Width.D32) -> list[int]:
        """Block read: the cycles of the block resolved once (the ADC buffer is read so each tick)."""
        key = (address, count, space, width)
        cycles = self._blocks.get(key) if type(width) is Width else None
        if cycles is None:
            am, w = self._check(address, space, width, write=False)
            am = self._block_am(am)
            cycles = tuple(self._cycle_for(am, address + i * w, w, False) for i in range(count))
            if type(width) is Width:
                self._remember(self._blocks, key, cycles)
        return [c() for c in cycles]

    def _read(self, am: AddressModifier, address: int, width: Width) -> int:
        return self._cycle_for(am, address, width, False)()

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        self._cycle_for(am, address, width, True)(value)

    @staticmethod
    def _remember(cache: dict, key: Any, value: Any) -> None:
        if len(cache) >= 4096:  # e.g. a large memory board swept once
            cache.clear()
        cache[key] = value

    def _cycle_for(self, am: AddressModifier, address: int, width: Width, write: bool) -> Any:
        key = (am, address, width, write)
        c = self._cycles.get(key)
        if c is None:
            c = self._resolve_cycle(am, address, width, write)
            self._remember(self._cycles, key, c)
        return c

    def invalidate(self) -> None:
        """Forget every resolved cycle (the crate's layout changed): the next cycle at each
        address decodes again, including cycles resolved by drivers' windows."""
        self._generation += 1
        self._cycles.clear()
        self._reads.clear()
        self._writes.clear()
        self._blocks.clear()

    def set_cycle_tap(self, tap: CycleTap | None) -> None:
        """Call ``tap`` after every cycle from now on (``None``: stop). It observes only: no cycle
        is added, none is timed differently. Without a tap the resolved cycles are the untapped
        ones, so a crate nobody traces pays nothing for it."""
        self._tap = tap
        self.invalidate()

    def _resolve_cycle(self, am: AddressModifier, address: int, width: Width, write: bool) -> Any:
        cycle = self._resolve_untapped(am, address, width, write)
        tap = self._tap
        return cycle if tap is None else self._tapped(cycle, tap, am, address, width, write)

    def _tapped(self, cycle: Any, tap: CycleTap, am: AddressModifier, address: int, width: Width,
                write: bool) -> Any:
        """``cycle`` reporting to ``tap`` (a cycle resolved before the layout changed resolves
        again, as the untapped ones do, so no cycle is reported twice)."""
        clock, generation = self.clock, self._generation

        if write:
            def write_tapped(value: int) -> None:
                if self._generation != generation:
                    return self._cycle_for(am, address, width, True)(value)  # type: ignore[no-any-return]
                try:
                    cycle(value)
                except BusError:
                    tap(clock.now_ns, am, address, width, True, value, True)
                    raise
                tap(clock.now_ns, am, address, width, True, value, False)
                return None

            return write_tapped

        def read_tapped() -> int:
            if self._generation != generation:
                return self._cycle_for(am, address, width, False)()  # type: ignore[no-any-return]
            try:
                value = cycle()
            except BusError:
                tap(clock.now_ns, am, address, width, False, 0, True)
                raise
            tap(clock.now_ns, am, address, width, False, value, False)
            return value  # type: ignore[no-any-return]

        return read_tapped

    def _resolve_untapped(self, am: AddressModifier, address: int, width: Width, write: bool) -> Any:
        ck = (write, am.code, width)
        key = self._counter_keys.get(ck)
        if key is None:
            key = self._counter_keys[ck] = f"{'write' if write else 'read'}.{am.space.name}.{width.name}"
        counters, clock, irq = self.counters, self.clock, self.irq
        generation = self._generation
        s = self._decode(am, address, width)
        if s is None:
            def nobody(*value: int) -> int:
                if self._generation != generation:
                    return self._cycle_for(am, address, width, write)(*value)  # type: ignore[no-any-return]
                counters[key] += 1
                return self._no_responder(am, address, width, write)

            return nobody
        board = s.board
        offset = address - s.base
        ns = int(board.cycle_ns(width, am.block))
        custom_removed = type(board).removed is not Board.removed  # a board that decides it itself
        # bus_read/bus_write replaced after resolution (a test pulling a board by patching its
        # instance or class): the cycle calls the replacement, as decoding every cycle did
        own = board.__dict__
        cls_read, cls_write = type(board).bus_read, type(board).bus_write

        def error(e: BoardAccessError) -> BusError:
            counters[f"error.{e.cause.name}"] += 1
            if irq.highest > irq.ipl:
                irq.service()
            return BusError(address, am, width, e.cause, e.detail, write=write)

        if write:
            put = board.writer(offset, width)

            def write_cycle(value: int) -> None:
                if self._generation != generation:
                    return self._cycle_for(am, address, width, True)(value)  # type: ignore[no-any-return]
                counters[key] += 1
                if (board.faulted or custom_removed) and board.removed:
                    self._no_responder(am, address, width, True)
                t = clock._now + ns
                if t < clock.next_due_ns:
                    clock._now = t
                else:
                    clock.advance_to(t)
                try:
                    if "bus_write" in own or type(board).bus_write is not cls_write:
                        board.bus_write(offset, width, value)
                    else:
                        put(value)
                except BoardAccessError as e:
                    raise error(e) from None
                if irq.highest > irq.ipl:
                    irq.service()
                return None

            return write_cycle
        get = board.reader(offset, width)

        def read_cycle() -> int:
            if self._generation != generation:
                return self._cycle_for(am, address, width, False)()  # type: ignore[no-any-return]
            counters[key] += 1
            if (board.faulted or custom_removed) and board.removed:
                self._no_responder(am, address, width, False)
            t = clock._now + ns
            if t < clock.next_due_ns:
                clock._now = t
            else:
                clock.advance_to(t)
            try:
                if "bus_read" in own or type(board).bus_read is not cls_read:
                    result = board.bus_read(offset, width)
                else:
                    result = get()
            except BoardAccessError as e:
                raise error(e) from None
            if irq.highest > irq.ipl:
                irq.service()
            return result

        return read_cycle

    def _no_responder(self, am: AddressModifier, address: int, width: Width, write: bool) -> int:
        """Nobody answers (no board, or a pulled one): the bus timer ends the cycle in BERR."""
        self.clock.advance(self.bus_timeout_ns)
        self.counters[f"error.{BusErrorCause.NO_RESPONDER.name}"] += 1
        self.irq.service()
        raise BusError(address, am, width, BusErrorCause.NO_RESPONDER, write=write)

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


def _checked_value(cycle: Callable[[int], None], width: Width, max_value: int, value: int) -> None:
    """:meth:`VmeBus.write`'s value check, then the resolved cycle with ``int(value)``."""
    v = int(value)
    if not 0 <= v <= max_value:
        raise VmeValueError(f"value {value} does not fit {width.name} (0..{max_value})")
    cycle(v)


def _checked_lane_value(cycle: Callable[[Any], None], width: Width, max_value: int, lanes: LaneSet,
                        value: Any) -> None:
    """:func:`_checked_value` on a crate of lanes: a lane array is checked lane by lane as
    ``int(value)`` and the range check would check it, and the live lanes where that raises are
    left (:meth:`LaneSet.eject`); the cycle carries int64 lanes (0 in lanes that failed)."""
    if type(value) is not np.ndarray:
        _checked_value(cycle, width, max_value, value)
        return
    v = value
    if v.dtype.kind == "f":  # int() truncates toward zero; it raises on NaN and inf
        with np.errstate(invalid="ignore"):
            bad = ~np.isfinite(v) | (v <= -1.0) | (v >= max_value + 1.0)
            v = v.astype(np.int64)
    else:  # integer words (the usual: codes, masks): nothing to warn about, no errstate to pay
        bad = (v < 0) | (v > max_value)
        v = v.astype(np.int64)  # a copy: the register must not share the caller's array
    if np.count_nonzero(bad):
        lanes.eject(bad, f"VmeValueError: value does not fit {width.name} (0..{max_value})")
        v = np.where(bad, 0, v)
    cycle(v)
