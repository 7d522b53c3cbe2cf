"""Typed VME errors. Every failed access names address, address modifier, width and cause."""

from __future__ import annotations

import enum

from hal.errors import HalError
from hal.vme.types import AddressModifier, Width


class VmeError(HalError):
    """Base class of every error raised by the VME layer."""


class BusErrorCause(enum.Enum):
    """Why a VME cycle ended in BERR*."""

    NO_RESPONDER = "no board decodes this address (bus timeout)"
    MISALIGNED = "address is not aligned to the data width"
    UNSUPPORTED_WIDTH = "the board does not support this data width here"
    ACCESS = "the register does not allow this access (read-only/write-only)"
    REMOTE = "the remote side of a bus bridge failed the cycle"
    LINK_DOWN = "the bus-bridge link is down or the remote crate is off"


class BusError(VmeError):
    """A VME cycle ended in a bus error (BERR*).

    Attributes:
        address: the byte address of the cycle.
        am: the address modifier used.
        width: the data width of the cycle.
        cause: why the cycle failed.
        detail: optional extra text from the responder.
    """

    def __init__(
        self,
        address: int,
        am: AddressModifier,
        width: Width,
        cause: BusErrorCause,
        detail: str = "",
        write: bool = False,
    ) -> None:
        self.address = address
        self.am = am
        self.width = width
        self.cause = cause
        self.detail = detail
        self.write = write
        op = "write" if write else "read"
        msg = (
            f"bus error on {width.name} {op} at {am.space.name} 0x{address:0{am.space.value // 4}X} "
            f"({am}): {cause.value}"
        )
        if detail:
            msg += f" — {detail}"
        super().__init__(msg)


class VmeConfigError(VmeError):
    """A crate or board configuration is invalid (overlap, bad base address, ...)."""


class BoardIdError(VmeConfigError):
    """A board's ID register does not read what its driver expects (wrong base address, wrong
    board, or wrong address space in the crate/rig file)."""
