"""Register map of the BIT3 VME-to-VME adaptor (after the Bit 3 Model 412/413), local card.

The card answers in two places on the local bus:

* a 16-byte block of control/status registers (CSR) in A16, declared below as
  :data:`BIT3_CSR`;
* a window in A24 or A32 (configurable base and size) that maps the remote crate's
  dual-port memory byte for byte (big-endian, D8/D16/D32, block transfers).

Status bits ``TIMEOUT``, ``REMOTE_BERR`` and ``PARITY`` are sticky: once set, every access
through the window ends in BERR until the driver resets the link (``COMMAND.RESET``), as on
the real card, where the interface error bits must be cleared before the next remote cycle.

Doorbells (programmed interrupts): writing ``DOORBELL_OUT`` rings the remote side with a
16-bit code; when the remote side rings, the card latches the code in ``DOORBELL_IN``, sets
``STATUS.DOORBELL`` and (if ``IRQ_CTRL.enable``) asserts IRQ ``IRQ_CTRL.level`` with status/ID
``IRQ_CTRL.vector``. The request is RORA: reading ``DOORBELL_IN`` acknowledges it.
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

CARD_ID = 0x0413  #: value of the ID register ("Model 413")

BIT3_CSR = RegisterMap(
    name="bit3",
    size=0x10,
    space=AddressSpace.A16,
    doc="BIT3 VME-to-VME adaptor, local control/status registers",
    registers=(
        Register(
            "STATUS", 0x00, Width.D16, Access.W1C,
            fields=(
                Field("link_up", 0, doc="cable connected and remote crate powered (live, RO)"),
                Field("remote_power", 1, doc="remote crate power on (live, RO)"),
                Field("timeout", 2, doc="sticky: a remote cycle timed out (link down / remote off)"),
                Field("remote_berr", 3, doc="sticky: the remote bus ended a cycle in BERR"),
                Field("parity", 4, doc="sticky: parity error on the link cable"),
                Field("doorbell", 5, doc="a doorbell from the remote side is pending (read DOORBELL_IN)"),
            ),
            doc="link and error status; write 1 to a sticky bit to clear it",
        ),
        Register(
            "COMMAND", 0x02, Width.D16, Access.RW,
            fields=(
                Field("reset", 0, doc="write 1: reset the link interface, clear sticky errors (self-clearing)"),
                Field("window_enable", 1, doc="1: the remote window answers (0: window cycles time out)"),
            ),
            reset=0x0002,
            doc="link control",
        ),
        Register(
            "IRQ_CTRL", 0x04, Width.D16, Access.RW,
            fields=(
                Field("level", 0, 3, doc="IRQ level 1..7 for the incoming doorbell (0: none)"),
                Field("enable", 3, doc="1: an incoming doorbell asserts the IRQ"),
                Field("vector", 8, 8, doc="8-bit status/ID returned on IACK"),
            ),
            doc="incoming-doorbell interrupt level, enable and vector",
        ),
        Register("DOORBELL_OUT", 0x06, Width.D16, Access.WO, doc="write a 16-bit code: ring the remote side"),
        Register(
            "DOORBELL_IN", 0x08, Width.D16, Access.RO,
            doc="code of the last doorbell from the remote side; reading acknowledges it (RORA)",
        ),
        Register("DOORBELL_COUNT", 0x0A, Width.D16, Access.RO, doc="doorbells received (mod 2^16)"),
        Register("ERRORS", 0x0C, Width.D16, Access.RO, doc="window cycles that ended in BERR (mod 2^16)"),
        Register("ID", 0x0E, Width.D16, Access.RO, reset=CARD_ID, doc="card identifier 0x0413"),
    ),
)

STICKY_ERROR_FIELDS = ("timeout", "remote_berr", "parity")
