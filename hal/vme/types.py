"""VME address spaces, data widths and address modifiers (ANSI/VITA 1-1994 codes).

Address modifier (AM) codes implemented:

======  =====  ===========  ==========
 AM     space  privilege    cycle
======  =====  ===========  ==========
 0x29   A16    user         data
 0x2D   A16    supervisory  data
 0x09   A32    user         data
 0x0A   A32    user         program
 0x0B   A32    user         block (BLT)
 0x0D   A32    supervisory  data
 0x0E   A32    supervisory  program
 0x0F   A32    supervisory  block (BLT)
 0x39   A24    user         data
 0x3A   A24    user         program
 0x3B   A24    user         block (BLT)
 0x3D   A24    supervisory  data
 0x3E   A24    supervisory  program
 0x3F   A24    supervisory  block (BLT)
======  =====  ===========  ==========
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from hal.errors import HalError


class VmeValueError(HalError, ValueError):
    """A VME name or value that is not one: an address space, a data width or an AM code that
    does not exist, an address outside its space, a value too wide for its data width. Bad input
    when a user gave it (``vmehil crate read A17 …``); a ``ValueError`` too."""


class AddressSpace(enum.Enum):
    """A VME address space; the value is the number of address bits."""

    A16 = 16
    A24 = 24
    A32 = 32

    # Members are singletons compared by identity: the identity hash agrees with that and is
    # computed in C (Enum's default hashes the member's name in Python, on every bus cycle's
    # cache lookup).
    __hash__ = object.__hash__

    @property
    def size(self) -> int:
        """Number of byte addresses in the space."""
        return 1 << self.value

    @classmethod
    def parse(cls, text: str | AddressSpace) -> AddressSpace:
        """Parse ``"A24"`` (case-insensitive) into an :class:`AddressSpace`."""
        if isinstance(text, AddressSpace):
            return text
        try:
            return cls[str(text).strip().upper()]
        except KeyError:
            raise VmeValueError(f"unknown address space {text!r}; expected one of A16, A24, A32") from None


class Width(enum.IntEnum):
    """A VME data width; the value is the number of bytes transferred."""

    D8 = 1
    D16 = 2
    D32 = 4

    # ``Width.D16 == 2``, so the hash must be the int's (Enum's default hashes the name, in
    # Python, and breaks the hash/equality contract with the plain ints it equals).
    __hash__ = int.__hash__

    @property
    def bits(self) -> int:
        return 8 * int(self)

    @property
    def max_value(self) -> int:
        return (1 << self.bits) - 1

    @classmethod
    def parse(cls, text: str | int | Width) -> Width:
        """Parse ``"D16"``, ``16`` (bits) or a :class:`Width`."""
        if type(text) is Width:
            return text
        if isinstance(text, int):
            for w in cls:
                if w.bits == text:
                    return w
            raise VmeValueError(f"unknown data width {text}; expected 8, 16 or 32")
        s = str(text).strip().upper()
        if s.isdigit():
            return cls.parse(int(s))
        try:
            return cls[s]
        except KeyError:
            raise VmeValueError(f"unknown data width {text!r}; expected D8, D16 or D32") from None


@dataclass(frozen=True)
class AddressModifier:
    """A decoded VME address modifier."""

    code: int
    space: AddressSpace
    supervisory: bool
    program: bool = False
    block: bool = False

    def __hash__(self) -> int:
        # Equal modifiers have equal codes; one int instead of hashing every field.
        return self.code

    def __str__(self) -> str:
        kind = "block" if self.block else ("program" if self.program else "data")
        priv = "super" if self.supervisory else "user"
        return f"AM 0x{self.code:02X} ({self.space.name} {priv} {kind})"


_AM_TABLE: dict[int, AddressModifier] = {}


def _add(code: int, space: AddressSpace, sup: bool, program: bool = False, block: bool = False):
    _AM_TABLE[code] = AddressModifier(code, space, sup, program, block)


_add(0x29, AddressSpace.A16, False)
_add(0x2D, AddressSpace.A16, True)
for _base, _space in ((0x08, AddressSpace.A32), (0x38, AddressSpace.A24)):
    _add(_base + 0x1, _space, False)
    _add(_base + 0x2, _space, False, program=True)
    _add(_base + 0x3, _space, False, block=True)
    _add(_base + 0x5, _space, True)
    _add(_base + 0x6, _space, True, program=True)
    _add(_base + 0x7, _space, True, block=True)


def decode_am(code: int) -> AddressModifier:
    """Return the :class:`AddressModifier` for ``code``; ``ValueError`` if it is not implemented."""
    try:
        return _AM_TABLE[code]
    except KeyError:
        known = ", ".join(f"0x{c:02X}" for c in sorted(_AM_TABLE))
        raise VmeValueError(f"address modifier 0x{code:02X} is not implemented (known: {known})") from None


def am_for(
    space: AddressSpace, *, supervisory: bool = True, program: bool = False, block: bool = False
) -> AddressModifier:
    """The address modifier for a space and cycle kind (A16 has no program or block cycles)."""
    for am in _AM_TABLE.values():
        if (am.space, am.supervisory, am.program, am.block) == (space, supervisory, program, block):
            return am
    raise VmeValueError(f"no address modifier for {space.name} program={program} block={block}")


def resolve_am(space: AddressSpace | AddressModifier | int | str) -> AddressModifier:
    """Accept a space (supervisory data AM), an AM code, an :class:`AddressModifier` or ``"A24"``."""
    cached = _RESOLVED.get(space)  # the hot path: a space or AM object seen before
    if cached is not None:
        return cached
    am = _resolve(space)
    if isinstance(space, AddressSpace | AddressModifier | str):
        _RESOLVED[space] = am
    return am


_RESOLVED: dict[object, AddressModifier] = {}


def _resolve(space: AddressSpace | AddressModifier | int | str) -> AddressModifier:
    if isinstance(space, AddressModifier):
        return space
    if isinstance(space, AddressSpace):
        return am_for(space)
    if isinstance(space, int):
        return decode_am(space)
    return am_for(AddressSpace.parse(space))
