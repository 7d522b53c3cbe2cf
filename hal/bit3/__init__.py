"""BIT3 VME-to-VME link: register map, driver, and the vision-servo protocol over its memory."""

from hal.bit3.driver import Bit3Driver, Bit3Status, Bit3WindowMemory
from hal.bit3.errors import Bit3Error, LinkDownError, ProtocolError, RemoteBusError
from hal.bit3.regs import BIT3_CSR, CARD_ID
from hal.shm import BufferMemory, Memory

__all__ = [
    "BIT3_CSR",
    "CARD_ID",
    "Bit3Driver",
    "Bit3Error",
    "Bit3Status",
    "Bit3WindowMemory",
    "BufferMemory",
    "LinkDownError",
    "Memory",
    "ProtocolError",
    "RemoteBusError",
]
