"""Register map of the SBS (Bit 3) Model 617 PCI-to-VME adaptor, as docs/boards/sbs617.md states it.

Two declarations: :data:`SBS617_NODE`, the 32-byte block of node registers (BAR 1; every
register one byte), and :data:`SBS617_MAP_ENTRY`, the form of a PCI→VME mapping-RAM entry
(BAR 2; entry *i* at 4·*i* translates 4 KiB page *i* of the window, BAR 3). Facts from NetBSD
``sys/dev/pci/btvmeireg.h`` and the Linux ``vmedrv`` driver's ``vmedrv_params.h`` (the doc cites
each). Offset 0x08 is two registers — read: Remote Status, write: Remote Command 1 — declared
once, as ``REM_CMD1_STATUS``, with the fields of both.
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

PCI_VENDOR_SBS = 0x108A  #: PCI configuration space, not readable through the BARs
PCI_DEVICE_617 = 0x0001

PAGE_SIZE = 0x1000  #: one window page / one PCI→VME map entry
MAP_ENTRIES = 8192  #: PCI→VME entries (0x0000..0x7FFF of the mapping RAM)
WINDOW_SIZE = PAGE_SIZE * MAP_ENTRIES  #: BAR 3, 32 MiB
MAP_RAM_SIZE = 0x10000  #: BAR 2
NODE_SIZE = 0x20  #: BAR 1

FUNCTION_REMOTE_RAM = 2  #: map-entry function code "remote bus RAM"
AM_A24_DATA = 0x39  #: A24 non-privileged data
AM_A32_DATA = 0x09  #: A32 non-privileged data


def _r(name: str, offset: int, access: Access, *fields: Field, reset: int = 0, doc: str = "") -> Register:
    return Register(name, offset, Width.D8, access, fields=tuple(fields), reset=reset, doc=doc)


SBS617_NODE = RegisterMap(
    name="sbs617",
    size=NODE_SIZE,
    space=AddressSpace.A32,
    doc="SBS/Bit 3 Model 617 node registers (local card 0x00-0x07, 0x10-0x16; remote card 0x08-0x0F, 0x18-0x1F)",
    registers=(
        _r("LOC_CMD1", 0x00, Access.RW,
           Field("CLR_ERROR", 7, doc="write 1: clear the LOC_STATUS error bits (one shot)"),
           Field("CLR_PR_INT", 6, doc="write 1: clear the PR interrupt (one shot)"),
           Field("SND_PT_INT", 5, doc="set the PT interrupt"),
           doc="Local Command Register"),
        _r("LOC_INT_CTRL", 0x01, Access.RW,
           Field("INT_ACT", 7, doc="RO: the card asserts its PCI interrupt"),
           Field("INT_EN", 6, doc="normal (PR, cable) interrupt enable"),
           Field("ERR_INT_EN", 5, doc="error interrupt enable"),
           Field("PT_CINT_SEL", 0, 3, doc="PT cable-interrupt line select"),
           doc="Local Interrupt Control Register"),
        _r("LOC_STATUS", 0x02, Access.RO,
           Field("PARITY_ERR", 7, doc="interface parity error PCI->remote"),
           Field("REMBUS_ERR", 6, doc="BERR from the remote VMEbus"),
           Field("PR_INT", 5, doc="PR interrupt received from the remote side"),
           Field("CARD_RDY", 4, doc="named in the source's diagram only"),
           Field("TIMEOUT_ERR", 2, doc="interface timeout PCI->remote"),
           Field("LRC_ERR", 1, doc="LRC error (DMA only)"),
           Field("NO_CONNECT", 0, doc="remote power or the I/O cable is off (live)"),
           doc="Local Status Register"),
        _r("LOC_INT_STATUS", 0x03, Access.RO, Field("CINT", 1, 7, doc="cable interrupts 7..1"),
           doc="Local Interrupt Status Register"),
        _r("PCI_CONTROL", 0x04, Access.RW, doc="bits not stated by the sources"),
        _r("REM_CMD1_STATUS", 0x08, Access.RW,
           Field("RESET", 7, doc="write: reset the remote bus"),
           Field("CLR_PT", 6, doc="write: clear the PT interrupt"),
           Field("SND_PR", 5, doc="write: send the PR interrupt to the remote side"),
           Field("LOCK_BUS", 4, doc="write: lock the remote bus"),
           Field("PG_SEL", 3, doc="write: page-mode access"),
           Field("IACK_LEVEL", 0, 3, doc="write: IRQ level of the next IACK read"),
           Field("WAS_RESET", 7, doc="read: the remote bus was reset"),
           Field("IACK_A1", 6, doc="read: IACK level bit 1"),
           Field("PR_SET", 5, doc="read: the PR interrupt is set"),
           Field("NOT_LOCKED", 4, doc="read: the remote bus is not locked"),
           Field("PG_MODE", 3, doc="read: page mode enabled"),
           Field("IACK_A2", 2, doc="read: IACK level bit 2"),
           Field("PT_SET", 1, doc="read: the PT interrupt is set"),
           Field("IACK_A0", 0, doc="read: IACK level bit 0"),
           doc="write: Remote Command Register 1; read: Remote Status Register"),
        _r("REM_CMD2", 0x09, Access.RW,
           Field("DMA_PAUSE", 7), Field("AMOD_SEL", 6), Field("DMA_BLK", 5), Field("CINT_DIS", 4),
           Field("PG_SIZE", 0, 4), doc="Remote Command Register 2"),
        _r("REM_PAGE_LO", 0x0A, Access.RW, doc="remote page A23-A16"),
        _r("REM_PAGE_HI", 0x0B, Access.RW, doc="remote page A31-A24"),
        _r("REM_CARD_ID", 0x0C, Access.RW, doc="Remote Card ID Register (read/write)"),
        _r("REM_AMOD", 0x0D, Access.RW, doc="remote address modifier"),
        _r("REM_IACK", 0x0E, Access.RO, doc="IACK read"),
        _r("REM_IACK_BYTE", 0x0F, Access.RO, doc="IACK read, byte form"),
        _r("LDMA_CMD", 0x10, Access.RW,
           Field("START", 7), Field("DP_SEL", 6), Field("WRITE_SEL", 5), Field("D32_SEL", 4),
           Field("INT_EN", 2), Field("DONE", 1), Field("ACTIVE", 0), doc="Local DMA Command Register"),
        _r("LDMA_RMD_CNT", 0x11, Access.RW),
        _r("LDMA_PKT_CNT_LO", 0x12, Access.RW),
        _r("LDMA_PKT_CNT_HI", 0x13, Access.RW),
        _r("LDMA_ADDR_LO", 0x14, Access.RW),
        _r("LDMA_ADDR_MID", 0x15, Access.RW),
        _r("LDMA_ADDR_HI", 0x16, Access.RW),
        _r("RDMA_LEN_CNT", 0x18, Access.RW),
        _r("RDMA_ADDR_A23", 0x1A, Access.RW),
        _r("RDMA_ADDR_A31", 0x1B, Access.RW),
        _r("RDMA_ADDR_A7", 0x1C, Access.RW),
        _r("RDMA_ADDR_A15", 0x1D, Access.RW),
        _r("REM_SLAVE_STATUS", 0x1F, Access.RO,
           Field("PARITY_ERR", 7), Field("REMBUS_ERR", 6), Field("PR_SET", 5), Field("TIMEOUT_ERR", 2),
           Field("PT_SET", 1), Field("NO_CONNECT", 0), doc="Remote Slave Status Register"),
    ),
)

SBS617_MAP_ENTRY = RegisterMap(
    name="sbs617-map",
    size=MAP_RAM_SIZE,
    space=AddressSpace.A32,
    doc="SBS/Bit 3 Model 617 mapping RAM: the form of PCI->VME entry i (at 4*i)",
    registers=(
        Register("PCI_VME_MAP", 0x0000, Width.D32, Access.RW, fields=(
            Field("VME_PAGE", 12, 20, doc="remote address A31-A12"),
            Field("AM", 6, 6, doc="VME address modifier"),
            Field("FUNCTION", 4, 2, doc="1 remote I/O, 2 remote RAM, 3 dual-port RAM"),
            Field("BYTE_SWAP", 3), Field("WORD_SWAP", 2), Field("WBYTE_SWAP", 1),
            Field("INVALID", 0, doc="1: the entry maps nothing"),
        ), doc="PCI->VME map entry"),
    ),
)

_LSR = SBS617_NODE["LOC_STATUS"]
#: the latched interface errors (btvmeireg.h ``LSR_ERROR_MASK``), cleared by LOC_CMD1.CLR_ERROR
LSR_LATCHED = sum(_LSR.field(n).mask for n in ("PARITY_ERR", "REMBUS_ERR", "TIMEOUT_ERR", "LRC_ERR"))
#: the link is not usable (``LSR_CERROR_MASK``): a latched error or NO_CONNECT
LSR_NOT_USABLE = LSR_LATCHED | _LSR.field("NO_CONNECT").mask
