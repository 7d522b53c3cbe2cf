"""Base classes for board emulators plugged into an emulated :class:`emulators.crate.Crate`.

A board decodes ``size`` bytes from its base address. The crate converts the board's
:class:`BoardAccessError` into a :class:`hal.vme.BusError` naming address, AM and width.
:class:`RegisterBoard` dispatches accesses on the shared :class:`hal.vme.RegisterMap`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial
from typing import Any, ClassVar, Protocol

from emulators.clock import SimClock
from emulators.errors import EmulatorError
from emulators.faults import FaultInjectable
from emulators.irq import IrqController
from emulators.signals import Signals
from hal.lanes import stack
from hal.vme.errors import BusErrorCause
from hal.vme.registers import Register, RegisterMap
from hal.vme.types import AddressSpace, Width


class Backplane(Protocol):
    """What a board uses of the crate it is installed in (:class:`emulators.crate.Crate`): the
    interrupt lines, the simulated clock and the nets. A protocol, so that boards do not import
    the crate, which is built on them."""

    irq: IrqController
    clock: SimClock
    signals: Signals


class BoardAccessError(EmulatorError):
    """Raised by a board to end the current cycle in BERR."""

    def __init__(self, cause: BusErrorCause, detail: str = "") -> None:
        self.cause = cause
        self.detail = detail
        super().__init__(detail or cause.value)


class Board(FaultInjectable):
    """An emulated VME board.

    Attributes:
        name: unique name in the crate.
        size: bytes decoded from the base address.
        base, space, slot: set when installed in a crate.
        irq_release: ``"roak"`` (release on acknowledge) or ``"rora"`` (release on register
            access: the board's own logic calls :meth:`release_irq`).
        access_ns: data-transfer time of one cycle (address to DTACK) in nanoseconds.
    """

    TYPE: ClassVar[str] = "board"
    FAULTS: ClassVar[dict[str, str]] = {
        "removed": "the board is pulled from the crate: every cycle to it ends in BERR after the bus timeout",
    }
    irq_release: str = "roak"
    access_ns: int = 300

    def __init__(self, name: str, size: int) -> None:
        self.name = name
        self.size = int(size)
        self.base = 0
        self.space = AddressSpace.A16
        self.slot: int = 0
        self.crate: Backplane | None = None
        self._irq_level = 0
        self._irq_vector = 0

    # --- crate hooks ---------------------------------------------------------------------
    def attach(self, crate: Backplane) -> None:
        """Called by the crate when the board is installed."""
        self.crate = crate

    def bus_read(self, offset: int, width: Width) -> int:
        raise NotImplementedError

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        raise NotImplementedError

    def reader(self, offset: int, width: Width) -> Callable[[], int]:
        """The read of ``width`` at ``offset`` as a callable, resolved once: the crate keeps
        it per address and calls it on every cycle there. ``reader(o, w)()`` is
        ``bus_read(o, w)`` (this default calls exactly that)."""
        return partial(self.bus_read, offset, width)

    def writer(self, offset: int, width: Width) -> Callable[[int], None]:
        """The write of ``width`` at ``offset``: ``writer(o, w)(v)`` is ``bus_write(o, w, v)``."""
        return partial(self.bus_write, offset, width)

    def cycle_ns(self, width: Width, block: bool) -> int:
        """Simulated duration of one data cycle at this board (the crate reads it once per
        address: a board's timing does not change while it is installed)."""
        t = self.access_ns + (100 if width is Width.D32 else 0)
        return t * 2 // 3 if block else t

    def reset(self) -> None:
        """Power-up / SYSRESET state."""
        self.release_irq()

    def describe(self) -> dict[str, Any]:
        """A short description for ``vmehil crate list``."""
        return {"type": self.TYPE}

    # --- lanes (batched lockstep: hal.lanes) ---------------------------------------------
    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> Board:
        """One board of ``crate`` (a crate of lanes, :meth:`emulators.crate.Crate.from_lanes`)
        holding the state of ``boards``, the same board of B scalar crates in lane order. A board
        type that has no lane form says so here: its rigs run one instance at a time."""
        raise NotImplementedError(f"board type {cls.TYPE!r} ({cls.__name__}) has no lane form")

    @classmethod
    def _adopt_passive(cls, boards: Sequence[Board], state: Callable[[Board], Any]) -> Board:
        """The lane form of a board nobody accesses in a tick (a RAM, an idle link card): lane 0's
        board itself, when every lane's board is in the same ``state`` (else no lane form: a lane
        value written to it later would have nowhere to go)."""
        first = state(boards[0])
        if any(b.faulted for b in boards) or any(state(b) != first for b in boards[1:]):
            raise NotImplementedError(f"board {boards[0].name!r} ({cls.TYPE}) differs between instances "
                                      "or has a fault: no lane form")
        return boards[0]

    # --- interrupts ----------------------------------------------------------------------
    def request_irq(self, level: int, vector: int) -> None:
        """Assert IRQ ``level`` (1..7); answer IACK with ``vector``."""
        if not 1 <= level <= 7:
            raise ValueError(f"{self.name}: IRQ level {level} is not 1..7")
        self._irq_level, self._irq_vector = level, vector & 0xFF
        if self.crate is not None:
            self.crate.irq.assert_line(self, level)

    def release_irq(self) -> None:
        if self._irq_level and self.crate is not None:
            self.crate.irq.release_line(self)
        self._irq_level = 0

    @property
    def irq_pending(self) -> bool:
        return self._irq_level != 0

    def iack(self, level: int) -> int:
        """Answer an interrupt-acknowledge cycle with the status/ID vector."""
        vector = self._irq_vector
        if self.irq_release == "roak":
            self.release_irq()
        return vector

    @property
    def removed(self) -> bool:
        """True while the ``removed`` fault is on (the crate then finds no responder here)."""
        return self.faulted and "removed" in self._faults()

    # --- time ----------------------------------------------------------------------------
    @property
    def now_ns(self) -> int:
        return self.crate.clock.now_ns if self.crate is not None else 0


class RegisterBoard(Board):
    """A board whose window is described by a :class:`RegisterMap`.

    Reads call ``read_<REG>()`` if the subclass defines it, else return the stored value;
    writes call ``write_<REG>(value)`` if defined, else store the value. Widths other than the
    register's own (plus ``Register.also``) end in BERR; so do reads of write-only and writes
    of read-only registers and accesses to holes in the map. A D8 access listed in ``also``
    reads/writes one byte of the register (big-endian: the lower address is the high byte).
    """

    REGMAP: ClassVar[RegisterMap]

    def __init__(self, name: str) -> None:
        super().__init__(name, self.REGMAP.size)
        self.regs: dict[str, int] = {}
        self.reset()

    def reset(self) -> None:
        super().reset()
        self.regs = {r.name: r.reset for r in self.REGMAP.registers}

    def _stack_regs(self, boards: Sequence[RegisterBoard]) -> None:
        """This (lane) board's registers: each register of ``boards`` stacked over the lanes
        (:func:`hal.lanes.stack`: a plain int where every lane holds the same)."""
        self.regs = {name: stack([b.regs[name] for b in boards]) for name in boards[0].regs}

    def _hook(self, prefix: str, name: str) -> Any:
        """The bound ``read_<REG>``/``write_<REG>`` hook (or None), looked up once per board
        (hooks may be methods or per-instance attributes set in ``__init__``)."""
        cache = self.__dict__.get("_hook_cache")
        if cache is None:
            cache = self.__dict__["_hook_cache"] = {}
        key = prefix + name
        if key not in cache:
            h = getattr(self, key, None)
            cache[key] = h if callable(h) else None
        return cache[key]

    def _locate(self, offset: int, width: Width) -> tuple[Register, int]:
        reg = self.REGMAP.containing(offset)
        if reg is None:
            raise BoardAccessError(BusErrorCause.NO_RESPONDER, f"{self.name}: no register at +0x{offset:X}")
        if width is not reg.width and width not in reg.also:
            raise BoardAccessError(
                BusErrorCause.UNSUPPORTED_WIDTH,
                f"{self.name}.{reg.name} is {reg.width.name}; {width.name} is not supported",
            )
        if int(width) > int(reg.width):
            raise BoardAccessError(BusErrorCause.UNSUPPORTED_WIDTH, f"{self.name}.{reg.name} too wide")
        return reg, offset - reg.offset

    # --- dispatch, resolved once per (offset, width) -------------------------------------
    # The register map is the one source of truth: the first access at an offset and width
    # locates the register, checks width and access and looks up the hook, exactly as every
    # access did before; the result (a callable, or one that raises the same BERR) is kept.
    def bus_read(self, offset: int, width: Width) -> int:
        return self._resolved_reader(offset, width)()

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        self._resolved_writer(offset, width)(value)

    def reader(self, offset: int, width: Width) -> Callable[[], int]:
        if type(self).bus_read is not RegisterBoard.bus_read:  # a subclass decodes itself
            return partial(self.bus_read, offset, width)
        return self._resolved_reader(offset, width)

    def writer(self, offset: int, width: Width) -> Callable[[int], None]:
        if type(self).bus_write is not RegisterBoard.bus_write:
            return partial(self.bus_write, offset, width)
        return self._resolved_writer(offset, width)

    def _resolved_reader(self, offset: int, width: Width) -> Callable[[], int]:
        return self._resolved("_readers", self._resolve_read, offset, width)

    def _resolved_writer(self, offset: int, width: Width) -> Callable[[int], None]:
        return self._resolved("_writers", self._resolve_write, offset, width)

    def _resolved(self, cache_name: str, resolve: Callable[[int, Width], Any], offset: int, width: Width) -> Any:
        """The access callable for ``(offset, width)``, resolved on first use and kept (in the
        instance dict: subclasses need not call our ``__init__``)."""
        cache = self.__dict__.setdefault(cache_name, {})
        key = (offset, width)
        f = cache.get(key)
        if f is None:
            f = cache[key] = resolve(offset, width)
        return f

    def _resolve_read(self, offset: int, width: Width) -> Callable[[], int]:
        """Locate the register once; the callable reads it (hook or stored value) and slices
        the bytes ``width`` covers. Subclasses may wrap it (the ADC notes buffer reads)."""
        try:
            reg, sub = self._locate(offset, width)
            if not reg.access.readable:
                raise BoardAccessError(BusErrorCause.ACCESS, f"{self.name}.{reg.name} is write-only")
        except BoardAccessError as e:
            return partial(_raise, e.cause, e.detail)
        handler = self._hook("read_", reg.name)
        name = reg.name
        shift = 8 * (int(reg.width) - sub - int(width))
        mask = width.max_value
        if handler is not None:
            if shift == 0:
                return lambda: handler() & mask
            return lambda: (handler() >> shift) & mask
        if shift == 0:
            return lambda: self.regs[name] & mask
        return lambda: (self.regs[name] >> shift) & mask

    def _resolve_write(self, offset: int, width: Width) -> Callable[[int], None]:
        try:
            reg, sub = self._locate(offset, width)
            if not reg.access.writable:
                raise BoardAccessError(BusErrorCause.ACCESS, f"{self.name}.{reg.name} is read-only")
        except BoardAccessError as e:
            return partial(_raise_on_write, e.cause, e.detail)
        handler = self._hook("write_", reg.name)
        name = reg.name
        if width is not reg.width:
            reg_width = reg.width

            def merged(value: int) -> None:
                value = _merge(self.regs[name], reg_width, sub, width, value)
                if handler is not None:
                    handler(value)
                else:
                    self.regs[name] = value

            return merged
        if handler is not None:
            return handler  # type: ignore[no-any-return]

        def store(value: int) -> None:
            self.regs[name] = value

        return store


def _raise(cause: BusErrorCause, detail: str) -> int:
    raise BoardAccessError(cause, detail)


def _raise_on_write(cause: BusErrorCause, detail: str, value: int) -> None:
    raise BoardAccessError(cause, detail)


def _merge(old: int, reg_width: Width, sub: int, width: Width, value: int) -> int:
    shift = 8 * (int(reg_width) - sub - int(width))
    mask = width.max_value << shift
    return (old & ~mask) | ((value << shift) & mask)
