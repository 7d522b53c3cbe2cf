"""The crate's cycle tap (a trace's view of the bus, docs/scope.md): every cycle is reported once,
after it ended, with what it did; it adds no cycle and moves no clock; cycles a caller resolved
before the tap was set report too; without a tap nothing is called."""

from __future__ import annotations

import pytest

from emulators.crate import Crate
from emulators.ram import RamBoard
from hal.vme import AddressSpace, BusError, Width


def crate_with_ram() -> Crate:
    crate = Crate("tap")
    crate.install(RamBoard("ram0", 0x100), base=0x1000, space=AddressSpace.A24)
    return crate


def test_every_cycle_is_reported_once_with_what_it_did() -> None:
    crate = crate_with_ram()
    seen: list[tuple] = []
    crate.set_cycle_tap(lambda t, am, a, w, write, v, berr: seen.append((am.space.name, a, int(w), write, v, berr, t)))
    crate.write(0x1010, 0xBEEF, space="A24", width=Width.D16)
    assert crate.read(0x1010, space="A24", width=Width.D16) == 0xBEEF
    assert crate.read_block(0x1010, 2, space="A24", width=Width.D16) == [0xBEEF, 0]
    with pytest.raises(BusError):
        crate.read(0x2000, space="A24", width=Width.D16)  # nobody there: BERR
    got = [s[:6] for s in seen]
    assert got == [("A24", 0x1010, 2, True, 0xBEEF, False), ("A24", 0x1010, 2, False, 0xBEEF, False),
                   ("A24", 0x1010, 2, False, 0xBEEF, False), ("A24", 0x1012, 2, False, 0, False),
                   ("A24", 0x2000, 2, False, 0, True)]
    times = [s[6] for s in seen]
    assert times == sorted(times) and times[0] > 0  # each at its end on the crate's clock


def test_the_tap_adds_no_cycle_and_moves_no_clock() -> None:
    plain, tapped = crate_with_ram(), crate_with_ram()
    tapped.set_cycle_tap(lambda *cycle: None)
    for crate in (plain, tapped):
        for i in range(8):
            crate.write(0x1000 + 2 * i, i * 3, space="A24", width=Width.D16)
            crate.read(0x1000 + 2 * i, space="A24", width=Width.D16)
    assert plain.counter_snapshot() == tapped.counter_snapshot()
    assert plain.clock.now_ns == tapped.clock.now_ns


def test_a_cycle_resolved_before_the_tap_reports_and_none_after_it_is_removed() -> None:
    crate = crate_with_ram()
    read = crate.reader(0x1004, space="A24", width=Width.D32)  # what a driver's window keeps
    read()
    seen: list[int] = []
    crate.set_cycle_tap(lambda t, am, a, w, write, v, berr: seen.append(a))
    read()
    read()
    crate.set_cycle_tap(None)
    read()
    assert seen == [0x1004, 0x1004]


def test_a_layout_change_under_a_tap_still_reports_each_cycle_once() -> None:
    crate = crate_with_ram()
    seen: list[int] = []
    crate.set_cycle_tap(lambda t, am, a, w, write, v, berr: seen.append(a))
    read = crate.reader(0x1008, space="A24", width=Width.D16)
    read()
    crate.install(RamBoard("ram1", 0x100), base=0x3000, space=AddressSpace.A24)  # the cycles resolve again
    read()
    assert seen == [0x1008, 0x1008]
