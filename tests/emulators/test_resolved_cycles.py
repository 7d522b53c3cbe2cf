"""The crate's resolved cycles (decode and register dispatch done once per address) behave
exactly as decoding every cycle did: the same values, the same bus errors, counters, time and
board state; a layout change or a pulled board is seen at once, also by cycles a driver's
window resolved earlier."""

from __future__ import annotations

import random
from functools import partial
from typing import Any

import pytest

from emulators.adc import AdcBoard
from emulators.board import Board, BoardAccessError, RegisterBoard
from emulators.crate import Crate
from emulators.dac import DacBoard
from emulators.pio import PioBoard
from emulators.quadrature import QuadratureBoard
from emulators.ram import RamBoard
from hal.vme import AddressSpace, BusError, BusErrorCause, Width
from hal.vme.types import AddressModifier, resolve_am
from hal.vme.window import BoardWindow


# --- the oracle: the crate cycle and register dispatch as they were, decoded every cycle ---------
def _reference_read(board: RegisterBoard, offset: int, width: Width) -> int:
    reg, sub = board._locate(offset, width)
    if not reg.access.readable:
        raise BoardAccessError(BusErrorCause.ACCESS, f"{board.name}.{reg.name} is write-only")
    handler = getattr(board, "read_" + reg.name, None)
    value = handler() if callable(handler) else board.regs[reg.name]
    if isinstance(board, AdcBoard) and reg.name.startswith("BUF"):
        board._note_read()
    shift = 8 * (int(reg.width) - sub - int(width))
    return (value >> shift) & width.max_value


def _reference_write(board: RegisterBoard, offset: int, width: Width, value: int) -> None:
    reg, sub = board._locate(offset, width)
    if not reg.access.writable:
        raise BoardAccessError(BusErrorCause.ACCESS, f"{board.name}.{reg.name} is read-only")
    if isinstance(board, AdcBoard) and reg.name == "CSR" and width is Width.D8 and sub == 0:
        value <<= 8  # the configuration byte alone: the action/status byte sees zeros (adc.md)
    elif width is not reg.width:
        shift = 8 * (int(reg.width) - sub - int(width))
        mask = width.max_value << shift
        value = (board.regs[reg.name] & ~mask) | ((value << shift) & mask)
    handler = getattr(board, "write_" + reg.name, None)
    if callable(handler):
        handler(value)
    else:
        board.regs[reg.name] = value


def _reference_cycle(crate: Crate, am: AddressModifier, address: int, width: Width, value: int | None) -> int:
    write = value is not None
    crate.counters[f"{'write' if write else 'read'}.{am.space.name}.{width.name}"] += 1
    s = crate._decode(am, address, width)
    if s is None or s.board.removed:
        crate.clock.advance(crate.bus_timeout_ns)
        crate.counters[f"error.{BusErrorCause.NO_RESPONDER.name}"] += 1
        crate.irq.service()
        raise BusError(address, am, width, BusErrorCause.NO_RESPONDER, write=write)
    board = s.board
    assert isinstance(board, RegisterBoard)
    crate.clock.advance(board.cycle_ns(width, am.block))
    try:
        if write:
            _reference_write(board, address - s.base, width, value)  # type: ignore[arg-type]
            result = 0
        else:
            result = _reference_read(board, address - s.base, width)
    except BoardAccessError as e:
        crate.counters[f"error.{e.cause.name}"] += 1
        crate.irq.service()
        raise BusError(address, am, width, e.cause, e.detail, write=write) from None
    crate.irq.service()
    return result


BASES = {"adc": 0x1000, "dac": 0x2000, "pio": 0x3000, "quad": 0x4000}
ADC_REGMAP = AdcBoard.REGMAP  # the emulator's own map (these tests are of the crate's dispatch)
ADC_BUFFER_OFFSET = ADC_REGMAP["BUF0"].offset


def _rack() -> Crate:
    crate = Crate("rack")
    crate.install(AdcBoard("adc", wiring={0: "a0", 1: "a1", 5: "a5"}, noise_rms_v=0.01, seed=4),
                  base=BASES["adc"], space="A16")
    crate.install(DacBoard("dac", wiring={0: "a0", 1: "d1"}), base=BASES["dac"], space="A16")
    crate.install(PioBoard("pio", lines={"PA0": "en", "PA1": "dir", "PB0": "flt"}, pwm_net="pwm"),
                  base=BASES["pio"], space="A16")
    crate.install(QuadratureBoard("quad", nets={0: "enc0"}), base=BASES["quad"], space="A16")
    for c, net in enumerate(("a0", "a1", "a5")):
        crate.signals.set_analog(net, 1.25 * (c + 1))
    crate.write(BASES["adc"] + ADC_REGMAP["VECTOR"].offset, 0x40)
    seen: list[tuple[int, int]] = []
    crate.interrupts_seen = seen  # type: ignore[attr-defined]

    def handler(vector: int) -> None:  # RORA: release the ADC's request (a cycle inside the handler)
        seen.append((vector, crate.clock.now_ns))
        crate.write(BASES["adc"] + ADC_REGMAP["CSR"].offset, _IRQ_PEND | _IRQ_ON)

    crate.register_irq_handler(0x40, handler)
    return crate


_IRQ_ON = (1 << 8) | (3 << 9)  # CSR: IRQ_EN, level 3
_IRQ_PEND = 1 << 7


def _outcome(fn: Any) -> tuple[str, Any]:
    try:
        return ("ok", fn())
    except (BusError, ValueError) as e:
        return (type(e).__name__, str(e))


def _state(crate: Crate) -> Any:
    boards = {n: dict(b.regs) for n, b in crate.boards.items() if isinstance(b, RegisterBoard)}
    return (dict(crate.counters), crate.clock.now_ns, crate.clock.pending(), boards,
            dict(crate.signals.analog), dict(crate.signals.digital), crate.irq.highest,
            list(crate.interrupts_seen), list(crate.irq.unhandled), crate.irq.storms)  # type: ignore[attr-defined]


def _write_both(fast: Crate, ref: Crate, address: int, width: Width, value: int) -> tuple[Any, Any]:
    am = resolve_am(AddressSpace.A16)
    got = _outcome(partial(fast.write, address, value, space=AddressSpace.A16, width=width))
    want = _outcome(partial(_reference_cycle, ref, am, address, width, value))
    return (got[0], 0 if got[0] == "ok" else got[1]), want


def _read_both(fast: Crate, ref: Crate, address: int, width: Width) -> tuple[Any, Any]:
    am = resolve_am(AddressSpace.A16)
    got = _outcome(partial(fast.read, address, space=AddressSpace.A16, width=width))
    return got, _outcome(partial(_reference_cycle, ref, am, address, width, None))


def _block_both(fast: Crate, ref: Crate, first: int, count: int) -> tuple[Any, Any]:
    am = resolve_am(AddressSpace.A16)
    got = _outcome(partial(fast.read_block, first, count, space=AddressSpace.A16, width=Width.D16))

    def reference() -> list[int]:
        return [_reference_cycle(ref, am, first + 2 * i, Width.D16, None) for i in range(count)]

    return got, _outcome(reference)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_resolved_cycles_match_decoding_every_cycle(seed: int) -> None:
    """Random reads, writes and block reads of every width over every board's whole window
    and the holes after it, with conversions and interrupts: the resolved path and the
    decode-every-cycle oracle agree after each cycle."""
    fast, ref = _rack(), _rack()
    rnd = random.Random(seed)
    adc = BASES["adc"]
    for step in range(3000):
        kind = rnd.choice(list(BASES))
        board = fast.board(kind)
        address = BASES[kind] + rnd.randrange(0, board.size + 8) // 2 * 2
        width = rnd.choice([Width.D8, Width.D16, Width.D16, Width.D32])
        address -= address % int(width)
        r = rnd.random()
        if r < 0.04:  # the driver's block read of the scan buffers
            got, want = _block_both(fast, ref, adc + ADC_BUFFER_OFFSET + 2 * rnd.randrange(0, 4), rnd.randrange(1, 6))
        elif r < 0.12:  # a conversion or scan with its end-of-conversion interrupt
            for reg, v in (("VECTOR", 0x40), ("SCAN_LAST", 3)):  # (a random write may have reset them)
                assert _write_both(fast, ref, adc + ADC_REGMAP[reg].offset, Width.D16, v) == (("ok", 0),) * 2
            got, want = _write_both(fast, ref, adc + ADC_REGMAP["CSR"].offset, Width.D16, _IRQ_ON | rnd.choice([1, 2]))
        elif r < 0.45:
            value = rnd.randrange(0, width.max_value + 1)
            if rnd.random() < 0.5:  # mostly harmless bits: do not reset the boards every cycle
                value &= 0x00F0
            got, want = _write_both(fast, ref, address, width, value)
        else:
            got, want = _read_both(fast, ref, address, width)
        assert got == want, f"step {step}: {kind} +0x{address - BASES[kind]:X} {width.name}"
        if rnd.random() < 0.05:  # let conversions, settling and interrupts happen
            dt = rnd.randrange(1, 40_000)
            fast.delay(dt * 1e-9)
            ref.delay(dt * 1e-9)
        assert _state(fast) == _state(ref), f"step {step}"
    assert len(fast.interrupts_seen) >= 3  # type: ignore[attr-defined]  # the interrupt path was exercised


def test_board_dispatch_is_resolved_once_from_the_register_map() -> None:
    """One resolved callable per (offset, width), reused; a reset (new regs dict) is seen."""
    crate = _rack()
    adc = crate.board("adc")
    assert isinstance(adc, AdcBoard)
    off = ADC_REGMAP["VECTOR"].offset
    assert adc.reader(off, Width.D16) is adc.reader(off, Width.D16)
    crate.write(BASES["adc"] + off, 0x42)
    assert crate.read(BASES["adc"] + off) == 0x42
    adc.reset()  # replaces the register dict
    assert crate.read(BASES["adc"] + off) == ADC_REGMAP["VECTOR"].reset
    # holes and wrong widths end in the same BERR as ever, every time
    for _ in range(2):
        with pytest.raises(BusError) as ei:
            crate.read(BASES["adc"] + off, width=Width.D32)
        assert ei.value.cause is BusErrorCause.UNSUPPORTED_WIDTH


def test_a_board_installed_later_answers_a_window_that_first_saw_no_responder() -> None:
    crate = Crate("late")
    win = BoardWindow(crate, 0x1000, ADC_REGMAP, "A16")
    with pytest.raises(BusError) as ei:
        win.read("VECTOR")
    assert ei.value.cause is BusErrorCause.NO_RESPONDER
    crate.install(AdcBoard("adc"), base=0x1000, space="A16")
    win.write("VECTOR", 0x5A)
    assert win.read("VECTOR") == 0x5A
    assert crate.counters["error.NO_RESPONDER"] == 1


def test_a_pulled_board_ends_resolved_cycles_in_berr_after_the_timeout_and_answers_again() -> None:
    crate = _rack()
    win = BoardWindow(crate, BASES["adc"], ADC_REGMAP, "A16")
    win.write("VECTOR", 0x11)
    assert win.read("VECTOR") == 0x11
    adc = crate.board("adc")
    adc.inject("removed")
    t0 = crate.clock.now_ns
    for op in (lambda: win.read("VECTOR"), lambda: win.write("VECTOR", 1)):
        with pytest.raises(BusError) as ei:
            op()
        assert ei.value.cause is BusErrorCause.NO_RESPONDER
    assert crate.clock.now_ns - t0 == 2 * crate.bus_timeout_ns
    adc.clear_fault("removed")
    assert win.read("VECTOR") == 0x11


class _SelfDecoding(Board):
    """A board (as a plug-in might be) with its own bus_read and its own idea of removal."""

    def __init__(self) -> None:
        super().__init__("custom", 0x10)
        self.gone = False
        self.reads = 0

    def bus_read(self, offset: int, width: Width) -> int:
        self.reads += 1
        return offset + self.reads

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        pass

    @property
    def removed(self) -> bool:  # type: ignore[override]
        return self.gone


def test_a_board_with_its_own_bus_read_and_removal_is_called_on_every_cycle() -> None:
    crate = Crate("c")
    b = crate.install(_SelfDecoding(), base=0x100, space="A16")
    assert [crate.read(0x104) for _ in range(3)] == [5, 6, 7]
    b.gone = True
    with pytest.raises(BusError):
        crate.read(0x104)


def test_writes_check_the_value_on_every_resolved_cycle() -> None:
    crate = _rack()
    crate.write(BASES["adc"] + ADC_REGMAP["VECTOR"].offset, 0xFF)
    with pytest.raises(ValueError, match="does not fit D16"):
        crate.write(BASES["adc"] + ADC_REGMAP["VECTOR"].offset, 0x10000)
    with pytest.raises(ValueError, match="does not fit D16"):
        crate.writer(BASES["adc"] + ADC_REGMAP["VECTOR"].offset)(-1)


def test_ram_block_transfers_through_resolved_cycles() -> None:
    crate = Crate("m")
    crate.install(RamBoard("ram", 0x100), base=0x200000, space="A24")
    crate.write_block(0x200000, [1, 2, 3, 0xFFFFFFFF])
    assert crate.read_block(0x200000, 4) == [1, 2, 3, 0xFFFFFFFF]
    assert crate.read(0x20000C, space="A24", width=Width.D16) == 0xFFFF
    assert crate.counters["write.A24.D32"] == 4 and crate.counters["read.A24.D32"] == 4


def test_bus_read_and_write_replaced_after_resolution_take_effect_at_once(monkeypatch) -> None:
    """Tests pull a board by replacing its bus_read/bus_write (instance or class) mid-run: the
    next cycle calls the replacement, also through a driver's already resolved window."""
    crate = _rack()
    win = BoardWindow(crate, BASES["adc"], ADC_REGMAP, "A16")
    win.write("VECTOR", 0x21)
    assert win.read("VECTOR") == 0x21
    adc = crate.board("adc")

    def berr(*a: Any, **k: Any) -> int:
        raise BoardAccessError(BusErrorCause.NO_RESPONDER, "board pulled from the crate")

    monkeypatch.setattr(adc, "bus_read", berr)
    monkeypatch.setattr(adc, "bus_write", berr)
    for op in (lambda: win.read("VECTOR"), lambda: win.write("VECTOR", 2)):
        with pytest.raises(BusError, match="board pulled"):
            op()
    monkeypatch.undo()
    assert win.read("VECTOR") == 0x21
    monkeypatch.setattr(AdcBoard, "bus_read", lambda self, offset, width: 0x77)
    assert win.read("VECTOR") == 0x77
