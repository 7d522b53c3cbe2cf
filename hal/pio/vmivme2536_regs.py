"""Register map of the VMIC VMIVME-2536 (32 optically coupled inputs, 32 outputs): the driver's
reading of docs/boards/vmivme2536.md.

The doc is the spec (tests/hal/test_vmivme2536_doc.py checks this map against its register
table); the emulator (``emulators.vmivme2536``) declares its own map from the same doc and
imports nothing here. The facts come from the Duke FEL EPICS support (hartmansm/DFELL_EPICS,
``vmi2536/drvVmi2536.h``): a 16-byte block in A16 supervisory short I/O — ``bid`` (D16),
``csr`` (D16), ``input`` (D32), ``output`` (D32), a reserved word — and three CSR bits that
turn the fail LED off and activate the outputs and the inputs. The ID value is not published:
the driver compares ``BID`` only with a value the rig states.
"""

from __future__ import annotations

import re

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

#: the ports a line belongs to: index 0 = the inputs (INPUT), 1 = the outputs (OUTPUT)
PORTS = ("IN", "OUT")
LINES_PER_PORT = 32

VMI2536_REGS = RegisterMap(
    "vmivme-2536",
    0x10,
    AddressSpace.A16,
    (
        Register("BID", 0x00, Width.D16, Access.RO, doc="board ID (value not published)"),
        Register(
            "CSR", 0x02, Width.D16, Access.RW,
            fields=(
                Field("led_off", 15, 1, "1: fail LED off"),
                Field("outputs_on", 14, 1, "1: outputs active"),
                Field("inputs_on", 13, 1, "1: inputs active"),
            ),
            doc="control and status",
        ),
        Register("INPUT", 0x04, Width.D32, Access.RO, doc="input channels, bit n = INn"),
        Register("OUTPUT", 0x08, Width.D32, Access.RW, doc="output latch, bit n = OUTn"),
    ),
    doc="32 optically coupled inputs and 32 outputs, no interrupt, no timer",
)

_PIN = re.compile(r"^(IN|OUT)([0-9]{1,2})$")


def parse_line(pin: str) -> tuple[int, int]:
    """``"OUT3"`` → (port 1, bit 3); ``"IN31"`` → (0, 31). Raises ``ValueError`` for anything else."""
    m = _PIN.match(pin.strip().upper())
    if m is None or int(m[2]) >= LINES_PER_PORT or (len(m[2]) == 2 and m[2][0] == "0"):
        raise ValueError(f"{pin!r} is not a VMIVME-2536 line; expected IN0..IN31 or OUT0..OUT31")
    return PORTS.index(m[1]), int(m[2])


ALL_LINES = tuple(f"{p}{b}" for p in PORTS for b in range(LINES_PER_PORT))
