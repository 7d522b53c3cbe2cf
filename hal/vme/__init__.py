"""The VME bus interface: address spaces, widths, modifiers, typed errors, register maps."""

from hal.vme.bus import IrqHandler, VmeBus
from hal.vme.errors import BoardIdError, BusError, BusErrorCause, VmeConfigError, VmeError
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressModifier, AddressSpace, VmeValueError, Width, am_for, decode_am, resolve_am
from hal.vme.window import BoardWindow

__all__ = [
    "Access",
    "AddressModifier",
    "AddressSpace",
    "BoardIdError",
    "BoardWindow",
    "BusError",
    "BusErrorCause",
    "Field",
    "IrqHandler",
    "Register",
    "RegisterMap",
    "VmeBus",
    "VmeConfigError",
    "VmeError",
    "VmeValueError",
    "Width",
    "am_for",
    "decode_am",
    "resolve_am",
]
