"""BIT3 vision link: the reference card, the SBS (Bit 3) Model 617, the vision-servo protocol over their memory."""

from hal.bit3.driver import Bit3Driver, Bit3Status, Bit3WindowMemory
from hal.bit3.errors import Bit3Error, LinkDownError, ProtocolError, RemoteBusError
from hal.bit3.regs import BIT3_CSR, CARD_ID
from hal.bit3.sbs617 import Sbs617Driver, Sbs617Status, Sbs617WindowMemory
from hal.bit3.sbs617_regs import SBS617_MAP_ENTRY, SBS617_NODE
from hal.shm import BufferMemory, Memory

__all__ = [
    "BIT3_CSR",
    "CARD_ID",
    "SBS617_MAP_ENTRY",
    "SBS617_NODE",
    "Bit3Driver",
    "Bit3Error",
    "Bit3Status",
    "Bit3WindowMemory",
    "BufferMemory",
    "LinkDownError",
    "Memory",
    "ProtocolError",
    "RemoteBusError",
    "Sbs617Driver",
    "Sbs617Status",
    "Sbs617WindowMemory",
]
