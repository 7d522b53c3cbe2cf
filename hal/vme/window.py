"""A driver's view of one board: registers accessed by name at ``base`` in ``space``."""

from __future__ import annotations

from collections.abc import Callable

from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BoardIdError
from hal.vme.registers import Register, RegisterMap
from hal.vme.types import AddressModifier, Width, resolve_am


class BoardWindow:
    """Register access for a driver: ``win.read("CSR")``, ``win.write_field("CSR", "start", 1)``."""

    def __init__(
        self, bus: VmeBus, base: int, regmap: RegisterMap, space: SpaceLike | None = None
    ) -> None:
        self.bus = bus
        self.base = base
        self.regmap = regmap
        self.am: AddressModifier = resolve_am(space if space is not None else regmap.space)
        # The bus cycle of each register, resolved once (VmeBus.reader/writer): a driver reads
        # the same registers every tick. Keyed by register name (natural width), or by
        # (offset, width) for read_offset/write_offset.
        self._readers: dict[str | tuple[int, Width], Callable[[], int]] = {}
        self._writers: dict[str | tuple[int, Width], Callable[[int], None]] = {}

    def _reg(self, reg: str | Register) -> Register:
        return reg if isinstance(reg, Register) else self.regmap[reg]

    def check_id(self, expected: int, kind: str, *, reg: str = "ID",
                  error: type[BoardIdError] = BoardIdError) -> None:
        """Read the board's ID register; raise ``error`` naming what was found where."""
        ident = self.read(reg)
        if ident != expected:
            raise error(
                f"no {kind} at 0x{self.base:X}: {reg} register reads 0x{ident:04X}, expected 0x{expected:04X}; "
                "check the base address in the crate/rig file"
            )

    def read(self, reg: str | Register, width: Width | None = None) -> int:
        if width is None and type(reg) is str:
            f = self._readers.get(reg)
            if f is None:
                r = self.regmap[reg]
                f = self._readers[reg] = self.bus.reader(self.base + r.offset, space=self.am, width=r.width)
            return f()
        r = self._reg(reg)
        return self.bus.read(self.base + r.offset, space=self.am, width=width or r.width)

    def write(self, reg: str | Register, value: int, width: Width | None = None) -> None:
        if width is None and type(reg) is str:
            f = self._writers.get(reg)
            if f is None:
                r = self.regmap[reg]
                f = self._writers[reg] = self.bus.writer(self.base + r.offset, space=self.am, width=r.width)
            f(value)
            return
        r = self._reg(reg)
        self.bus.write(self.base + r.offset, value, space=self.am, width=width or r.width)

    def read_field(self, reg: str | Register, name: str) -> int:
        r = self._reg(reg)
        return r.field(name).get(self.read(r))

    def write_fields(self, reg: str | Register, **fields: int) -> None:
        """Write a register built from named fields (other bits 0)."""
        r = self._reg(reg)
        self.write(r, r.pack(**fields))

    def modify(self, reg: str | Register, **fields: int) -> int:
        """Read-modify-write the named fields; returns the value written."""
        r = self._reg(reg)
        value = self.read(r)
        for name, v in fields.items():
            value = r.field(name).put(value, int(v))
        self.write(r, value)
        return value

    def read_offset(self, offset: int, width: Width) -> int:
        f = self._readers.get((offset, width)) if type(width) is Width else None
        if f is None:
            f = self.bus.reader(self.base + offset, space=self.am, width=width)
            if type(width) is Width:
                self._readers[(offset, width)] = f
        return f()

    def write_offset(self, offset: int, value: int, width: Width) -> None:
        f = self._writers.get((offset, width)) if type(width) is Width else None
        if f is None:
            f = self.bus.writer(self.base + offset, space=self.am, width=width)
            if type(width) is Width:
                self._writers[(offset, width)] = f
        f(value)
