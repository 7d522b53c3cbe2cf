"""The VME bus interface that every driver talks to, and nothing else.

A :class:`VmeBus` is either an emulated crate (``emulators.crate.Crate``) or, later, a real
VME master. Drivers call :meth:`VmeBus.read`/:meth:`VmeBus.write` with an address, an address
space or modifier and a data width; values are unsigned integers in the bus's big-endian byte
order (the 68020 host is big-endian, so a D32 at address A is bytes A..A+3, most significant
first). Failed cycles raise :class:`hal.vme.errors.BusError`; they never read as 0.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

from hal.lanes import LaneSet
from hal.vme.errors import BusError, BusErrorCause
from hal.vme.types import AddressModifier, AddressSpace, VmeValueError, Width, am_for, resolve_am

IrqHandler = Callable[[int], None]
"""An interrupt handler; called with the 8-bit status/ID vector it was registered for."""

SpaceLike = AddressSpace | AddressModifier | int | str


class VmeBus(ABC):
    """Abstract VME bus master.

    Subclasses implement :meth:`_read`, :meth:`_write`, :meth:`now` and :meth:`delay`. The
    base class normalizes arguments, checks alignment and value range, and keeps the
    per-vector interrupt handler table.
    """

    #: the lanes of a batch this bus carries (hal.lanes): ``None`` for one instance (every bus but
    #: an emulated crate in lane mode); then each value read or written may be a lane array
    lanes: LaneSet | None = None

    def __init__(self) -> None:
        self._irq_handlers: dict[int, IrqHandler] = {}

    def decide(self, cond: Any, reason: str) -> bool:
        """The branch a driver takes on ``cond``, a value read from this bus or computed from one:
        ``bool(cond)`` on a bus of one instance; on a bus of lanes, the live lanes' common answer
        (:meth:`hal.lanes.LaneSet.decide`: lanes that would branch the other way are left, with
        ``reason``)."""
        lanes = self.lanes
        return bool(cond) if lanes is None else lanes.decide(cond, reason)

    # --- single cycles -------------------------------------------------------------------
    def read(self, address: int, *, space: SpaceLike = AddressSpace.A16, width: Width = Width.D16) -> int:
        """Read one value (unsigned int) of ``width`` at ``address`` in ``space``."""
        am, width = self._check(address, space, width, write=False)
        return self._read(am, address, width)

    def write(
        self, address: int, value: int, *, space: SpaceLike = AddressSpace.A16, width: Width = Width.D16
    ) -> None:
        """Write ``value`` (unsigned, must fit ``width``) at ``address`` in ``space``."""
        am, width = self._check(address, space, width, write=True)
        if not 0 <= int(value) <= width.max_value:
            raise VmeValueError(f"value {value} does not fit {width.name} (0..{width.max_value})")
        self._write(am, address, width, int(value))

    # --- resolved cycles -----------------------------------------------------------------
    def reader(self, address: int, *, space: SpaceLike = AddressSpace.A16,
               width: Width = Width.D16) -> Callable[[], int]:
        """The read of one fixed address, space and width as a callable: ``reader(...)()`` is
        ``read(...)``. Callers that access the same register every tick (a driver's
        :class:`hal.vme.window.BoardWindow`) resolve it once; the address is checked here
        (a misaligned or out-of-space address raises now, as :meth:`read` would). A bus may
        resolve the cycle itself (the emulated crate decodes the board and register once);
        this default performs the checked cycle on every call.
        """
        if type(self).read is not VmeBus.read:  # a subclass with its own read(): call it
            return partial(self.read, address, space=space, width=width)
        am, w = self._check(address, space, width, write=False)
        return partial(self._read, am, address, w)

    def writer(self, address: int, *, space: SpaceLike = AddressSpace.A16,
               width: Width = Width.D16) -> Callable[[int], None]:
        """The write of one fixed address, space and width: ``writer(...)(value)`` is
        ``write(..., value)`` (the value is range-checked on every call)."""
        if type(self).write is not VmeBus.write:
            return partial(_call_write, self.write, address, space, width)
        am, w = self._check(address, space, width, write=True)
        return partial(_checked_write, self._write, am, address, w, w.max_value)

    # --- block transfers -----------------------------------------------------------------
    def read_block(
        self, address: int, count: int, *, space: SpaceLike = AddressSpace.A24, width: Width = Width.D32
    ) -> list[int]:
        """Read ``count`` consecutive values with block (BLT) cycles where the space has them."""
        am, width = self._check(address, space, width, write=False)
        am = self._block_am(am)
        return [self._read(am, address + i * width, width) for i in range(count)]

    def write_block(
        self, address: int, values: Sequence[int], *, space: SpaceLike = AddressSpace.A24,
        width: Width = Width.D32,
    ) -> None:
        """Write consecutive values with block (BLT) cycles where the space has them."""
        am, width = self._check(address, space, width, write=True)
        am = self._block_am(am)
        for i, v in enumerate(values):
            if not 0 <= int(v) <= width.max_value:
                raise VmeValueError(f"value {v} at index {i} does not fit {width.name}")
            self._write(am, address + i * width, width, int(v))

    # --- interrupts ----------------------------------------------------------------------
    def register_irq_handler(self, vector: int, handler: IrqHandler) -> None:
        """Call ``handler(vector)`` when an interrupter answers IACK with ``vector`` (0..255)."""
        if not 0 <= vector <= 0xFF:
            raise ValueError(f"interrupt vector {vector} is not an 8-bit status/ID")
        if vector in self._irq_handlers:
            raise ValueError(f"interrupt vector 0x{vector:02X} already has a handler")
        self._irq_handlers[vector] = handler

    def unregister_irq_handler(self, vector: int) -> None:
        """Remove the handler of ``vector`` (no error if there is none)."""
        self._irq_handlers.pop(vector, None)

    def irq_handler(self, vector: int) -> IrqHandler | None:
        return self._irq_handlers.get(vector)

    # --- time ----------------------------------------------------------------------------
    @abstractmethod
    def now(self) -> float:
        """Bus time in seconds: simulated time on an emulated crate, monotonic time on hardware."""

    @abstractmethod
    def delay(self, seconds: float) -> None:
        """Let ``seconds`` of bus time pass (emulation advances its clock; hardware sleeps)."""

    # --- backend hooks -------------------------------------------------------------------
    @abstractmethod
    def _read(self, am: AddressModifier, address: int, width: Width) -> int: ...

    @abstractmethod
    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None: ...

    # --- helpers -------------------------------------------------------------------------
    def _check(self, address: int, space: SpaceLike, width: Width | str | int, *, write: bool):
        am = resolve_am(space)
        width = Width.parse(width)
        if not 0 <= address < am.space.size:
            raise VmeValueError(
                f"address 0x{address:X} is outside {am.space.name} (0..0x{am.space.size - 1:X})"
            )
        if address % int(width):
            raise BusError(address, am, width, BusErrorCause.MISALIGNED, write=write)
        return am, width

    @staticmethod
    def _block_am(am: AddressModifier) -> AddressModifier:
        if am.space is AddressSpace.A16 or am.block:
            return am
        return am_for(am.space, supervisory=am.supervisory, block=True)


def _call_write(write: Callable[..., None], address: int, space: SpaceLike, width: Width, value: int) -> None:
    write(address, value, space=space, width=width)


def _checked_write(write: Callable[[AddressModifier, int, Width, int], None], am: AddressModifier, address: int,
                   width: Width, max_value: int, value: int) -> None:
    if not 0 <= int(value) <= max_value:
        raise VmeValueError(f"value {value} does not fit {width.name} (0..{max_value})")
    write(am, address, width, int(value))
