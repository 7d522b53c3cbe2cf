"""Golden bus traces: a VME bus that records every cycle a driver makes.

A :class:`RecordingBus` either forwards each cycle to another bus (an emulated crate) or answers
reads from a script written by the test (``answers``), so a driver's cycles can be compared with a
literal trace written by hand from the board's documentation (docs/boards/<board>.md)::

    bus = RecordingBus(answers={("A16", 0x4000): 0xAD16})
    probe(bus, base=0x4000)
    assert bus.trace() == ["R A16 0x4000 D16 0xAD16"]

A trace line is ``<R|W> <space> 0x<address> <width> 0x<value>``, with ``BLT`` appended for a block
(BLT) cycle; :func:`parse_cycle` reads the same text back. ``delay(s)`` calls are kept apart
(:attr:`RecordingBus.delays`) so a trace stays a list of bus cycles. The expected trace of a test
is never captured from the driver and pasted: it is the doc's sequence, written out.

No tests here; trace tests import it as ``tests.support.bus_trace``.
"""

from __future__ import annotations

import re
from collections import deque
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from hal.vme.bus import VmeBus
from hal.vme.errors import BusError, BusErrorCause
from hal.vme.types import AddressModifier, Width

#: what a scripted read of one (space, address) answers: a value, a sequence of values (the
#: last repeats once the others are used up), or a function of the number of earlier reads
Answer = int | Iterable[int] | Callable[[int], int]

_LINE = re.compile(
    r"^(?P<op>[RW])\s+(?P<space>A16|A24|A32)\s+0x(?P<address>[0-9A-Fa-f]+)\s+(?P<width>D8|D16|D32)"
    r"\s+0x(?P<value>[0-9A-Fa-f]+)(?P<blt>\s+BLT)?$"
)


@dataclass(frozen=True)
class Cycle:
    """One bus cycle: direction, address space, address, data width (bytes) and value."""

    op: str
    space: str
    address: int
    width: int
    value: int
    block: bool = False

    def __str__(self) -> str:
        digits = 2 * self.width
        text = f"{self.op} {self.space} 0x{self.address:X} D{8 * self.width} 0x{self.value:0{digits}X}"
        return text + (" BLT" if self.block else "")


def parse_cycle(text: str) -> Cycle:
    """The :class:`Cycle` a trace line names (case of the hex digits is free)."""
    m = _LINE.match(text.strip())
    if m is None:
        raise ValueError(f"not a trace line: {text!r} (expected e.g. 'W A16 0x4002 D16 0x0001')")
    return Cycle(m["op"], m["space"], int(m["address"], 16), int(m["width"][1:]) // 8, int(m["value"], 16),
                 m["blt"] is not None)


class RecordingBus(VmeBus):
    """A bus that records every cycle; forwards to ``inner`` or answers from ``answers``.

    Scripted reads of an address the script does not name end in a :class:`BusError` (no
    responder), as they would on a crate with nothing there; scripted writes are only recorded.
    Interrupt handlers go to ``inner`` when there is one, so a crate's interrupts still reach
    the driver.
    """

    def __init__(self, inner: VmeBus | None = None, *, answers: Mapping[tuple[str, int], Answer] | None = None) -> None:
        super().__init__()
        if inner is not None and answers:
            raise ValueError("a RecordingBus forwards to a bus or answers from a script, not both")
        self.inner = inner
        self.cycles: list[Cycle] = []
        self.delays: list[float] = []
        self._time_s = 0.0
        self._reads: dict[tuple[str, int], int] = {}
        self._answers: dict[tuple[str, int], Callable[[int], int]] = {
            key: _answer_function(a) for key, a in (answers or {}).items()
        }

    # --- the trace -----------------------------------------------------------------------
    def trace(self) -> list[str]:
        """The recorded cycles as trace lines."""
        return [str(c) for c in self.cycles]

    def clear(self) -> None:
        """Forget the cycles and delays recorded so far (e.g. after a set-up the test does not check)."""
        self.cycles.clear()
        self.delays.clear()

    # --- VmeBus --------------------------------------------------------------------------
    def _read(self, am: AddressModifier, address: int, width: Width) -> int:
        if self.inner is not None:
            value = self.inner.read(address, space=am, width=width)
        else:
            key = (am.space.name, address)
            answer = self._answers.get(key)
            if answer is None:
                raise BusError(address, am, width, BusErrorCause.NO_RESPONDER, write=False)
            n = self._reads.get(key, 0)
            self._reads[key] = n + 1
            value = answer(n)
        self.cycles.append(Cycle("R", am.space.name, address, int(width), value, am.block))
        return value

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        self.cycles.append(Cycle("W", am.space.name, address, int(width), value, am.block))
        if self.inner is not None:
            self.inner.write(address, value, space=am, width=width)

    def now(self) -> float:
        return self.inner.now() if self.inner is not None else self._time_s

    def delay(self, seconds: float) -> None:
        self.delays.append(seconds)
        if self.inner is not None:
            self.inner.delay(seconds)
        else:
            self._time_s += seconds

    def register_irq_handler(self, vector: int, handler: Callable[[int], None]) -> None:
        if self.inner is not None:
            self.inner.register_irq_handler(vector, handler)
        else:
            super().register_irq_handler(vector, handler)

    def unregister_irq_handler(self, vector: int) -> None:
        if self.inner is not None:
            self.inner.unregister_irq_handler(vector)
        else:
            super().unregister_irq_handler(vector)

    def irq_handler(self, vector: int) -> Callable[[int], None] | None:
        return self.inner.irq_handler(vector) if self.inner is not None else super().irq_handler(vector)


def _answer_function(answer: Answer) -> Callable[[int], int]:
    if callable(answer):
        return answer
    if isinstance(answer, int):
        value = answer
        return lambda _n: value
    values = deque(answer)
    if not values:
        raise ValueError("an answer sequence needs at least one value")
    seq = list(values)
    return lambda n: seq[min(n, len(seq) - 1)]
