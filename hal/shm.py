"""Shared memory as plain bytes: any byte-addressable store, with no register meaning.

:class:`Memory` is the interface (offsets and sizes in bytes; what the bytes mean is the
business of whoever reads them). Implementations:

* :class:`BufferMemory` — a ``bytearray``, ``memoryview`` or
  ``multiprocessing.shared_memory.SharedMemory(...).buf`` (the vision computer's view of its
  own dual-port memory, or a test's direct view);
* ``hal.bit3.driver.Bit3WindowMemory`` — the robot's view through the BIT3 window (VME bus
  cycles; failures raise ``hal.bit3.errors.Bit3Error``);
* test doubles that delay or tear writes.

It lives outside the driver packages because both ends of a shared-memory link use it: the
driver side and the emulators (which may import no driver package). It was
``hal.bit3.memory`` (that name stays as an alias).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable


@runtime_checkable
class Memory(Protocol):
    """Byte-addressable shared memory. Implementations may raise their own error on access
    (the BIT3 window raises ``Bit3Error``)."""

    def read(self, offset: int, size: int) -> bytes:
        """Return ``size`` bytes starting at byte ``offset``."""
        ...

    def write(self, offset: int, data: bytes) -> None:
        """Store ``data`` starting at byte ``offset``."""
        ...


class BufferMemory:
    """:class:`Memory` over a writable buffer (``bytearray``, ``memoryview``, shared memory)."""

    def __init__(self, buffer: Any, offset: int = 0, size: int | None = None) -> None:
        mv = memoryview(buffer).cast("B")
        end = len(mv) if size is None else offset + size
        if offset < 0 or end > len(mv):
            raise ValueError(f"region {offset}..{end} does not fit a buffer of {len(mv)} bytes")
        self.mem = mv[offset:end]

    @property
    def size(self) -> int:
        return len(self.mem)

    def read(self, offset: int, size: int) -> bytes:
        self._check(offset, size)
        return bytes(self.mem[offset : offset + size])

    def write(self, offset: int, data: bytes) -> None:
        self._check(offset, len(data))
        self.mem[offset : offset + len(data)] = data

    def _check(self, offset: int, size: int) -> None:
        if offset < 0 or offset + size > len(self.mem):
            raise IndexError(f"access {offset}..{offset + size} outside memory of {len(self.mem)} bytes")

    def release(self) -> None:
        """Drop the view (needed before closing a shared-memory segment)."""
        self.mem.release()
