"""VME interrupts: priority levels, daisy chain, status/ID vectors, ROAK and RORA release."""

from __future__ import annotations

import pytest

from emulators.board import Board
from emulators.crate import Crate
from hal.vme import Width


class Interrupter(Board):
    """A minimal interrupter: any write to offset 0 releases (RORA) its request."""

    def __init__(self, name: str, release: str = "roak") -> None:
        super().__init__(name, 0x10)
        self.irq_release = release
        self.clears = 0

    def bus_read(self, offset, width):
        return 0

    def bus_write(self, offset, width, value):
        self.clears += 1
        self.release_irq()


def _crate(*boards: tuple[Interrupter, int]) -> Crate:
    c = Crate()
    for i, (b, slot) in enumerate(boards):
        c.install(b, base=0x100 * (i + 1), space="A16", slot=slot)
    return c


def test_highest_level_is_served_first_and_vectors_reach_their_handlers() -> None:
    lo, hi = Interrupter("lo"), Interrupter("hi")
    c = _crate((lo, 2), (hi, 3))
    seen: list[int] = []
    c.register_irq_handler(0x40, seen.append)
    c.register_irq_handler(0x41, seen.append)
    c.irq.ipl = 7  # mask while both assert
    lo.request_irq(2, 0x40)
    hi.request_irq(5, 0x41)
    c.irq.ipl = 0
    c.delay(1e-6)
    assert seen == [0x41, 0x40]
    assert c.counter_snapshot()["iack.IRQ5"] == 1


def test_same_level_daisy_chain_favours_the_lower_slot() -> None:
    a, b = Interrupter("a"), Interrupter("b")
    c = _crate((a, 7), (b, 3))
    seen: list[int] = []
    c.register_irq_handler(1, seen.append)
    c.register_irq_handler(2, seen.append)
    c.irq.ipl = 7
    a.request_irq(3, 1)
    b.request_irq(3, 2)
    c.irq.ipl = 0
    c.delay(0)
    assert seen == [2, 1]


def test_roak_releases_on_acknowledge() -> None:
    b = Interrupter("b", "roak")
    c = _crate((b, 2))
    calls: list[int] = []
    c.register_irq_handler(0x80, calls.append)
    b.request_irq(4, 0x80)
    c.delay(0)  # interrupts are taken at the next bus cycle or delay
    assert calls == [0x80] and not b.irq_pending


def test_rora_holds_until_the_handler_touches_the_board() -> None:
    b = Interrupter("b", "rora")
    c = _crate((b, 2))
    calls: list[int] = []

    def handler(vector: int) -> None:
        calls.append(vector)
        c.write(0x100, 0, space="A16", width=Width.D16)  # clear the source

    c.register_irq_handler(0x81, handler)
    b.request_irq(4, 0x81)
    c.delay(0)
    assert calls == [0x81] and b.clears == 1 and not b.irq_pending


def test_rora_handler_that_forgets_to_clear_is_a_counted_storm() -> None:
    b = Interrupter("b", "rora")
    c = _crate((b, 2))
    calls: list[int] = []
    c.register_irq_handler(0x82, calls.append)
    b.request_irq(4, 0x82)
    c.delay(0)
    assert len(calls) == c.irq.storm_limit
    assert c.counter_snapshot()["irq.storms"] >= 1
    assert b.irq_pending


def test_lower_level_waits_while_a_higher_handler_runs() -> None:
    lo, hi = Interrupter("lo"), Interrupter("hi")
    c = _crate((lo, 2), (hi, 3))
    order: list[str] = []

    def hi_handler(v: int) -> None:
        order.append("hi-start")
        lo.request_irq(1, 0x11)  # arrives during the level-6 handler
        c.read(0x100, space="A16", width=Width.D16)
        order.append("hi-end")

    c.register_irq_handler(0x10, hi_handler)
    c.register_irq_handler(0x11, lambda v: order.append("lo"))
    hi.request_irq(6, 0x10)
    c.delay(0)
    assert order == ["hi-start", "hi-end", "lo"]


def test_unhandled_vector_is_recorded() -> None:
    b = Interrupter("b")
    c = _crate((b, 2))
    b.request_irq(2, 0x99)
    c.delay(0)
    assert c.irq.unhandled == [0x99]


def test_handler_registration_rules() -> None:
    c = Crate()
    c.register_irq_handler(5, lambda v: None)
    with pytest.raises(ValueError, match="already"):
        c.register_irq_handler(5, lambda v: None)
    with pytest.raises(ValueError):
        c.register_irq_handler(256, lambda v: None)
    c.unregister_irq_handler(5)
    c.register_irq_handler(5, lambda v: None)
