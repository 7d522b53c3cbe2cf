"""hal.vme: resolved cycles (VmeBus.reader/writer) are the checked read/write of their address
on any bus, and a BoardWindow resolves each register once; the types' hashes agree with
their equality."""

from __future__ import annotations

import pytest

from hal.vme import AddressSpace, BusError, BusErrorCause, Width
from hal.vme.bus import VmeBus
from hal.vme.registers import Access, Register, RegisterMap
from hal.vme.types import AddressModifier, am_for, decode_am, resolve_am
from hal.vme.window import BoardWindow


class _Bus(VmeBus):
    """A minimal bus: a dict of words, a log of cycles."""

    def __init__(self) -> None:
        super().__init__()
        self.mem: dict[int, int] = {}
        self.log: list[tuple[str, int, int, Width]] = []

    def now(self) -> float:
        return 0.0

    def delay(self, seconds: float) -> None:
        pass

    def _read(self, am: AddressModifier, address: int, width: Width) -> int:
        self.log.append(("r", am.code, address, width))
        return self.mem.get(address, 0)

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        self.log.append(("w", am.code, address, width))
        self.mem[address] = value


def test_a_resolved_cycle_is_the_checked_cycle_of_its_address() -> None:
    bus = _Bus()
    put = bus.writer(0x100, space="A16", width=Width.D16)
    get = bus.reader(0x100, space="A16", width=Width.D16)
    put(0xBEEF)
    assert get() == 0xBEEF == bus.read(0x100, space="A16", width=Width.D16)
    with pytest.raises(ValueError, match="does not fit D16"):
        put(0x10000)
    assert bus.log == [("w", 0x2D, 0x100, Width.D16), ("r", 0x2D, 0x100, Width.D16), ("r", 0x2D, 0x100, Width.D16)]
    with pytest.raises(BusError) as ei:  # the address is checked when the cycle is resolved
        bus.reader(0x101, width=Width.D16)
    assert ei.value.cause is BusErrorCause.MISALIGNED
    with pytest.raises(ValueError, match="outside A16"):
        bus.writer(0x10000)


class _OwnRead(_Bus):
    def read(self, address: int, *, space=AddressSpace.A16, width: Width = Width.D16) -> int:
        return 42


def test_a_bus_with_its_own_read_is_called_by_its_resolved_cycles() -> None:
    assert _OwnRead().reader(0x100)() == 42


_MAP = RegisterMap("toy", 0x10, AddressSpace.A16, (
    Register("A", 0x0, Width.D16, Access.RW),
    Register("B", 0x4, Width.D32, Access.RW),
))


def test_a_window_resolves_each_register_once_and_keeps_other_widths_checked() -> None:
    bus = _Bus()
    win = BoardWindow(bus, 0x2000, _MAP)
    calls: list[tuple[int, Width]] = []
    resolve = bus.reader

    def counting_reader(address: int, **kw) -> object:
        calls.append((address, kw["width"]))
        return resolve(address, **kw)

    bus.reader = counting_reader  # type: ignore[method-assign]
    win.write("B", 7)
    assert [win.read("B") for _ in range(3)] == [7, 7, 7]
    assert calls == [(0x2004, Width.D32)]
    assert win.read(_MAP["B"]) == 7  # by Register object: the plain checked path
    assert win.read("B", Width.D16) == 7 and bus.log[-1] == ("r", 0x2D, 0x2004, Width.D16)
    with pytest.raises(KeyError):
        win.read("C")


def test_hashes_agree_with_equality() -> None:
    assert hash(Width.D16) == hash(2) and {Width.D16: "x"}[2] == "x"
    assert hash(AddressSpace.A24) == hash(AddressSpace.A24)
    assert resolve_am(AddressSpace.A24) == am_for(AddressSpace.A24) == decode_am(0x3D)
    same = AddressModifier(0x3D, AddressSpace.A24, True)
    assert same == decode_am(0x3D) and hash(same) == hash(decode_am(0x3D))
    assert {decode_am(0x3D): 1}[same] == 1


def test_a_window_resolves_each_offset_and_width_once_and_still_checks_the_value() -> None:
    bus = _Bus()
    win = BoardWindow(bus, 0x2000, _MAP)
    resolved: list[tuple[int, Width]] = []
    reader, writer = bus.reader, bus.writer

    def counting(resolve):  # type: ignore[no-untyped-def]
        def f(address: int, **kw):  # type: ignore[no-untyped-def]
            resolved.append((address, kw["width"]))
            return resolve(address, **kw)
        return f

    bus.reader, bus.writer = counting(reader), counting(writer)  # type: ignore[method-assign]
    for v in (0x12, 0x34):
        win.write_offset(0x1, v, Width.D8)
        assert win.read_offset(0x1, Width.D8) == v
    win.write_offset(0x0, 0x5678, Width.D16)
    assert resolved == [(0x2001, Width.D8), (0x2001, Width.D8), (0x2000, Width.D16)]
    assert bus.log[-1] == ("w", 0x2D, 0x2000, Width.D16) and len(bus.log) == 5  # every cycle made
    with pytest.raises(ValueError, match="does not fit D8"):
        win.write_offset(0x1, 0x100, Width.D8)
