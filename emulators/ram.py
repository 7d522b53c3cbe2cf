"""A plain RAM board: any width, any alignment the bus allows, big-endian.

Used by tests (read-after-write properties) and as the dual-port memory behind the BIT3
window. The storage may be any writable buffer (``bytearray`` or a
``multiprocessing.shared_memory`` buffer), so a RAM board can be shared across processes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from emulators.board import Board
from hal.vme.types import Width


class RamBoard(Board):
    """``size`` bytes of RAM answering D8, D16 and D32 cycles."""

    TYPE = "ram"
    access_ns = 200

    def __init__(self, name: str, size: int, buffer: Any = None) -> None:
        super().__init__(name, size)
        self.mem = memoryview(buffer if buffer is not None else bytearray(size)).cast("B")
        if len(self.mem) < size:
            raise ValueError(f"{name}: buffer of {len(self.mem)} bytes is smaller than size {size}")

    def bus_read(self, offset: int, width: Width) -> int:
        return int.from_bytes(self.mem[offset : offset + int(width)], "big")

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        self.mem[offset : offset + int(width)] = value.to_bytes(int(width), "big")

    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> Board:
        """Lane 0's RAM when every lane's holds the same bytes (no tick accesses a RAM)."""
        return cls._adopt_passive(boards, lambda b: bytes(b.mem) if isinstance(b, RamBoard) else None)

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "size": self.size}
