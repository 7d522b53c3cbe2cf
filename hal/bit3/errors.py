"""Typed errors of the BIT3 link driver and the vision-servo protocol."""

from __future__ import annotations

from hal.vme.errors import BusError, VmeError


class Bit3Error(VmeError):
    """Base class: something on the BIT3 link failed."""


class LinkDownError(Bit3Error):
    """A window access failed because the link is down, the remote crate is off, or a sticky
    interface error is latched. Check the cable and remote power, then ``Bit3Driver.reset_link()``.

    Attributes:
        bus_error: the underlying :class:`hal.vme.BusError` (``None`` if found by a status check).
        status: the card's STATUS register when the error was diagnosed (``None`` if unreadable).
    """

    def __init__(self, message: str, bus_error: BusError | None = None, status: int | None = None) -> None:
        super().__init__(message)
        self.bus_error = bus_error
        self.status = status


class RemoteBusError(Bit3Error):
    """The remote crate's bus ended a window cycle in BERR (or a parity error on the cable).
    The card latches the error; ``Bit3Driver.reset_link()`` clears it."""

    def __init__(self, message: str, bus_error: BusError | None = None, status: int | None = None) -> None:
        super().__init__(message)
        self.bus_error = bus_error
        self.status = status


class ProtocolError(Bit3Error):
    """The shared-memory layout is missing or of another version (wrong magic/version)."""
