"""Register map of the parallel I/O board (PIO): the driver's reading of docs/boards/pio.md.

The doc is the spec (tests/hal/test_pio.py checks this map against its register table); the
emulator (``emulators.pio``) declares its own map from the same doc and imports nothing here.

Inspired by the Motorola MC68230 PI/T as used on VME parallel-I/O cards of the era (Xycom
XVME-240-style): byte-wide ports with a data direction register each, an output latch that
is written whatever the direction, *alternate* registers that read the pins themselves, a
port interrupt with a programmable status/ID vector, and a timer (here a PWM generator for
an H-bridge). A16 short I/O, 0x20 bytes, big-endian; port registers are D8, the rest D16.

Ports A, B, C (8 lines each, named ``PA0``..``PC7``):

- ``DDR_x`` (RW): 1 = output, 0 = input; power-up 0 (all inputs).
- ``DATA_x`` (RW): a write loads the output latch (every bit, inputs included, as on the
  68230 — a line switched to output drives whatever the latch holds); a read returns the
  latch for output lines and the pin level for input lines.
- ``PIN_x`` (RO): the pin levels of all eight lines (what the wire really is: an output that
  is shorted or stuck reads differently here than in ``DATA_x``).
- ``IER_x`` (RW): input-change interrupt enable mask.
- ``ICS_x`` (RW1C): input-change status: bit set when an input line's pin level changed.

``INT_CTL``: [15:8] status/ID vector, [7] IEN, [2:0] IRQ level (1..7). The board holds its
request (RORA) while any ``ICS_x & IER_x`` bit is set: the handler must clear them.

PWM timer: 10 MHz clock (100 ns tick). ``PWM_PERIOD`` and ``PWM_DUTY`` in ticks; output
high for ``DUTY`` ticks of every ``PERIOD``; ``DUTY >= PERIOD`` is 100 %, ``PERIOD = 0``
holds the output low.
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

BOARD_TYPE = 0x50  #: ID[15:8] of this board type ("P")
REVISION = 0x01
PWM_CLOCK_HZ = 10_000_000  #: PWM timer clock (one tick = 100 ns)
PORTS = ("A", "B", "C")
LINES_PER_PORT = 8

_ID = Register(
    "ID", 0x00, Width.D16, Access.RO,
    fields=(Field("type", 8, 8, "board type 0x50"), Field("rev", 0, 8, "revision")),
    reset=(BOARD_TYPE << 8) | REVISION,
    doc="board identification (read-only)",
)


def _port_regs() -> list[Register]:
    regs: list[Register] = []
    for i, p in enumerate(PORTS):
        regs += [
            Register(f"DDR_{p}", 0x02 + i, Width.D8, Access.RW, doc=f"port {p} direction, 1 = output"),
            Register(f"DATA_{p}", 0x06 + i, Width.D8, Access.RW,
                     doc=f"port {p} data: write = output latch; read = latch (outputs) / pin (inputs)"),
            Register(f"PIN_{p}", 0x0A + i, Width.D8, Access.RO, doc=f"port {p} pin levels (alternate register)"),
            Register(f"IER_{p}", 0x0E + i, Width.D8, Access.RW, doc=f"port {p} input-change interrupt enable"),
            Register(f"ICS_{p}", 0x12 + i, Width.D8, Access.W1C, doc=f"port {p} input-change status, write 1 to clear"),
        ]
    return regs


PIO_REGS = RegisterMap(
    "pio",
    0x20,
    AddressSpace.A16,
    (
        _ID,
        *_port_regs(),
        Register(
            "INT_CTL", 0x16, Width.D16, Access.RW,
            fields=(
                Field("vector", 8, 8, "status/ID answered on IACK"),
                Field("ien", 7, 1, "input-change interrupt enable"),
                Field("level", 0, 3, "IRQ level 1..7 (0 = none)"),
            ),
            doc="interrupt level, enable and vector",
        ),
        Register("PWM_CTL", 0x18, Width.D16, Access.RW, fields=(Field("enable", 0, 1, "PWM output running"),),
                 doc="PWM control"),
        Register("PWM_PERIOD", 0x1A, Width.D16, Access.RW, doc="PWM period in 100 ns ticks (0 = output low)"),
        Register("PWM_DUTY", 0x1C, Width.D16, Access.RW, doc="PWM high time in 100 ns ticks (>= period: 100 %)"),
        Register("PWM_COUNT", 0x1E, Width.D16, Access.RO, doc="PWM counter now, ticks into the period"),
    ),
    doc="three 8-bit ports, input-change interrupt, PWM timer",
)


def parse_line(pin: str) -> tuple[int, int]:
    """``"PB3"`` → (port index 1, bit 3). Raises ``ValueError`` for anything else."""
    s = pin.strip().upper()
    if len(s) == 3 and s[0] == "P" and s[1] in PORTS and s[2] in "01234567":
        return PORTS.index(s[1]), int(s[2])
    raise ValueError(f"{pin!r} is not a PIO line; expected PA0..PA7, PB0..PB7 or PC0..PC7")


ALL_LINES = tuple(f"P{p}{b}" for p in PORTS for b in range(LINES_PER_PORT))
