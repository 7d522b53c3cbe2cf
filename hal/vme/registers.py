"""The one way a board's registers are declared: a :class:`RegisterMap` of :class:`Register`
objects (offset from the board base, width, access, reset value) with named bit :class:`Field`
objects.

The declaration *style* is shared; the declarations are not. A driver declares its board's map
in its own package (``hal/<area>/<board>_regs.py``) and accesses registers by name through
:class:`hal.vme.window.BoardWindow`; the board's emulator declares its own map, written from the
board's documentation (``docs/boards/<board>.md``, the spec), and dispatches bus cycles on it.
Tests check each map against the doc's register table separately (``tests/support/board_spec``),
so a wrong bit in one is caught instead of being copied into the other.
"""

from __future__ import annotations

import enum
from collections.abc import Iterable
from dataclasses import dataclass, field

from hal.vme.types import AddressSpace, Width


class Access(enum.Enum):
    """Register access kinds."""

    RO = "RO"  #: read-only; writes end in BERR
    WO = "WO"  #: write-only; reads end in BERR
    RW = "RW"  #: read/write
    W1C = "RW1C"  #: read; writing 1 to a bit clears it

    @property
    def readable(self) -> bool:
        return self is not Access.WO

    @property
    def writable(self) -> bool:
        return self is not Access.RO


@dataclass(frozen=True)
class Field:
    """A bit field of a register: ``width`` bits starting at bit ``lsb``."""

    name: str
    lsb: int
    width: int = 1
    doc: str = ""

    @property
    def mask(self) -> int:
        return ((1 << self.width) - 1) << self.lsb

    def get(self, value: int) -> int:
        """Extract this field from a register value."""
        return (value & self.mask) >> self.lsb

    def put(self, value: int, field_value: int) -> int:
        """Return ``value`` with this field replaced by ``field_value``."""
        if not 0 <= field_value < (1 << self.width):
            raise ValueError(f"{field_value} does not fit the {self.width}-bit field {self.name}")
        return (value & ~self.mask) | (field_value << self.lsb)


@dataclass(frozen=True)
class Register:
    """One register of a board.

    Attributes:
        name: identifier used by driver and emulator.
        offset: byte offset from the board base address.
        width: the register's natural width; the board answers BERR for other widths unless
            they are listed in ``also``.
        access: read/write semantics.
        fields: named bit fields (empty for a plain data register).
        reset: value after power-up/reset.
        doc: one line for the docs table (units and scaling).
        also: extra widths the board accepts at this offset (e.g. D8 reads of a D16 register).
    """

    name: str
    offset: int
    width: Width
    access: Access
    fields: tuple[Field, ...] = ()
    reset: int = 0
    doc: str = ""
    also: tuple[Width, ...] = ()

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"register {self.name} has no field {name!r}")

    def pack(self, **fields: int) -> int:
        """Build a register value from field values (unnamed bits are 0)."""
        value = 0
        for name, v in fields.items():
            value = self.field(name).put(value, int(v))
        return value

    def unpack(self, value: int) -> dict[str, int]:
        return {f.name: f.get(value) for f in self.fields}


@dataclass(frozen=True)
class RegisterMap:
    """The register map of one board type.

    Attributes:
        name: board type name.
        size: bytes of address space the board decodes from its base.
        space: address space it normally sits in.
        registers: the registers (offsets must not overlap).
    """

    name: str
    size: int
    space: AddressSpace
    registers: tuple[Register, ...]
    doc: str = ""
    _by_name: dict[str, Register] = field(default_factory=dict, init=False, repr=False, compare=False)
    _by_offset: dict[int, Register] = field(default_factory=dict, init=False, repr=False, compare=False)
    _by_byte: dict[int, Register] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        spans: list[tuple[int, int, str]] = []
        for r in self.registers:
            if r.name in self._by_name:
                raise ValueError(f"{self.name}: duplicate register name {r.name}")
            if r.offset % int(r.width):
                raise ValueError(f"{self.name}.{r.name}: offset 0x{r.offset:X} not aligned")
            if r.offset + int(r.width) > self.size:
                raise ValueError(f"{self.name}.{r.name}: beyond the board window")
            for lo, hi, other in spans:
                if r.offset < hi and lo < r.offset + int(r.width):
                    raise ValueError(f"{self.name}: registers {other} and {r.name} overlap")
            spans.append((r.offset, r.offset + int(r.width), r.name))
            self._by_name[r.name] = r
            self._by_offset[r.offset] = r
            for b in range(r.offset, r.offset + int(r.width)):
                self._by_byte[b] = r

    def __getitem__(self, name: str) -> Register:
        try:
            return self._by_name[name]
        except KeyError:
            raise KeyError(f"{self.name} has no register {name!r}") from None

    def at(self, offset: int) -> Register | None:
        """The register starting at ``offset``, or ``None``."""
        return self._by_offset.get(offset)

    def containing(self, offset: int) -> Register | None:
        """The register whose bytes include ``offset``, or ``None``."""
        return self._by_byte.get(offset)


def fields(*items: Field) -> tuple[Field, ...]:
    """Convenience for declaring a tuple of fields."""
    return tuple(items)


def registers(items: Iterable[Register]) -> tuple[Register, ...]:
    return tuple(items)
