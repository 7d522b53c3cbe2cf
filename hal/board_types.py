"""The board types a rig file names (``type = "adc"``), driver side: one plain table.

In the style of python-can's ``BACKENDS``: board-type name → a :class:`BoardType`, which holds the
board's descriptive metadata (vendor, model, the document it follows), its *role* (what the
servo's joint I/O uses it as) and two ``"module:attr"`` strings — the driver factory and the
probe — imported on first use only. So this module imports no driver package, and ``emulators``
(which must not) may read the table. Installed distributions add types through the entry points
of group ``vmehil.board_drivers`` (each names a :class:`BoardType`), read by the one plug-in
mechanism, :class:`hal.plugins.PluginTable`. The emulator factories keep their own table under
the same names (``emulators.board_types.BOARD_TYPES``, group ``vmehil.board_types``); a test
checks that the two tables name the same types. Adding a board: one entry here, one there, and
its modules (docs/architecture.md, "Adding a board").

Roles and the driver factory each takes (the servo's joint I/O builds them so; a new board of a
role is wired exactly like the reference board of that role):

==========  ===========================================================================
``adc``     ``factory(bus, base, *, space)``; ``factory.CHANNELS``: its channel count
``dac``     ``factory(bus, base, *, space, clamp)``; ``factory.CHANNELS``
``pio``     ``factory(bus, base, *, space, lines)`` (lines ``{net: "PA0"..."PC7"}``)
``quad``    ``factory(bus, base, *, space, counts_per_rev, channels, errors)``; ``factory.CHANNELS``
``bit3``    ``factory(bus, csr_base, window_base, *, csr_space, window_space, ...)`` (the vision link)
``ram``     no driver: memory, read and written as plain bytes
==========  ===========================================================================

The probe identifies a board in the dry pass on a real bus (``vmehil --bus vme_user``): either a
:class:`hal.vme.registers.RegisterMap` whose ``ID`` register's reset value is the ID the board
answers (read by :class:`RegisterProbe`), or a callable :data:`Probe`. No probe: the board has
no ID register (it must answer at its base).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from typing import Any

from hal.plugins import PluginTable
from hal.vme.bus import VmeBus
from hal.vme.errors import VmeError
from hal.vme.registers import Register, RegisterMap
from hal.vme.types import AddressSpace, Width

#: what a board can be to the servo's joint I/O (see the module's docstring)
ROLES = ("adc", "dac", "pio", "quad", "bit3", "ram")
#: where a board sits (:attr:`BoardType.bus`)
BUSES = ("vme", "pci")

DriverFactory = Callable[..., Any]
"""A driver factory: ``(bus, base, *, space, **role options) -> driver`` (a driver class is one)."""


@dataclass(frozen=True)
class ProbeReading:
    """What a probe read of one board: whether it is the board the rig names, the ID it expected
    and read (None: the board has no ID register, or the read failed), and a one-line detail."""

    ok: bool
    detail: str
    id_expected: int | None = None
    id_read: int | None = None


Probe = Callable[[VmeBus, int, AddressSpace], ProbeReading]
"""``probe(bus, base, space) -> ProbeReading``: reads only; never writes."""

#: the status/control registers a register-map probe also reads (the first readable one)
_STATUS_NAMES = ("CSR", "STATUS", "CTRL", "CONTROL")


@dataclass(frozen=True)
class RegisterProbe:
    """The probe of a board with an ``ID`` register in its map: read it against its reset value
    (the ID the doc gives), then the first readable status/control register."""

    regmap: RegisterMap

    def __call__(self, bus: VmeBus, base: int, space: AddressSpace) -> ProbeReading:
        ident = self.regmap["ID"]
        parts: list[str] = []
        try:
            got = bus.read(base + ident.offset, space=space, width=ident.width)
        except VmeError as e:
            return ProbeReading(False, f"{type(e).__name__}: {e}", ident.reset)
        if got != ident.reset:
            return ProbeReading(False, f"ID reads 0x{got:X}", ident.reset, got)
        parts.append(f"ID 0x{got:X}")
        status = next((r for r in self.regmap.registers if r.name in _STATUS_NAMES and r.access.readable), None)
        if status is not None:
            try:
                v = bus.read(base + status.offset, space=space, width=status.width)
            except VmeError as e:
                return ProbeReading(False, "; ".join([*parts, f"{type(e).__name__}: {e}"]), ident.reset, got)
            parts.append(f"{status.name} 0x{v:X}")
        return ProbeReading(True, "; ".join(parts), ident.reset, got)


@cache
def _resolve(ref: str) -> Any:
    """``"package.module:Attr.attr"`` → the object (imported on first use, then kept)."""
    module, sep, attr = ref.partition(":")
    if not sep or not module or not attr:
        raise ValueError(f"{ref!r} is not a 'module:attribute' reference")
    obj: Any = importlib.import_module(module)
    for part in attr.split("."):
        obj = getattr(obj, part)
    return obj


@dataclass(frozen=True)
class BoardType:
    """One board type: its role, its metadata, and where its driver and probe live (lazily)."""

    role: str
    vendor: str
    model: str
    #: the spec the board follows (a path in this repository, or a reference for a plug-in's)
    document: str
    #: ``"module:attr"`` of the driver factory; None: no driver (memory)
    driver: str | None = None
    #: ``"module:attr"`` of a RegisterMap with an ``ID`` register, or of a :data:`Probe`; None: no ID
    probe: str | None = None
    #: where the board sits: ``"vme"`` (a VME slot), or ``"pci"`` (a card in the robot's host: its
    #: registers are PCI BARs, in the emulated crate's A32 space only — a VME bus cannot reach them)
    bus: str = "vme"

    def __post_init__(self) -> None:
        if self.role not in ROLES:
            raise ValueError(f"board role {self.role!r} is not one of {', '.join(ROLES)}")
        if self.bus not in BUSES:
            raise ValueError(f"board bus {self.bus!r} is not one of {', '.join(BUSES)}")

    def metadata(self) -> dict[str, str]:
        """``vendor``, ``model``, ``document``: what ``vmehil crate list`` shows per board."""
        return {"vendor": self.vendor, "model": self.model, "document": self.document}

    def load_driver(self) -> DriverFactory:
        if self.driver is None:
            raise LookupError(f"a {self.role} board ({self.model}) has no driver")
        factory = _resolve(self.driver)
        if not callable(factory):
            raise TypeError(f"{self.driver!r} is not a driver factory")
        return factory  # type: ignore[no-any-return]

    def channels(self) -> int | None:
        """The driver's channel count (``CHANNELS``; None if it declares none, or has no driver)."""
        if self.driver is None:
            return None
        n = getattr(self.load_driver(), "CHANNELS", None)
        return n if isinstance(n, int) else None

    def load_probe(self) -> Probe | None:
        if self.probe is None:
            return None
        obj = _resolve(self.probe)
        if isinstance(obj, RegisterMap):
            return RegisterProbe(obj)
        if not callable(obj):
            raise TypeError(f"{self.probe!r} is neither a RegisterMap nor a probe")
        return obj  # type: ignore[no-any-return]

    def id_register(self) -> Register | None:
        """The ID register (offset, width, the ID as its reset value), if its probe is a
        register map's: for naming the board a wrong slot holds."""
        probe = self.load_probe()
        return probe.regmap["ID"] if isinstance(probe, RegisterProbe) else None

    def describe(self) -> str:
        """``ADC16-REF by vmehil (reference design), docs/boards/adc.md``"""
        return f"{self.model} by {self.vendor}, {self.document}"


_REFERENCE = "vmehil (reference design)"

BUILTIN_BOARD_TYPES: dict[str, BoardType] = {
    "adc": BoardType("adc", _REFERENCE, "ADC16-REF", "docs/boards/adc.md",
                     driver="hal.adc_dac.adc:AdcDriver", probe="hal.adc_dac.adc_regs:ADC_REGMAP"),
    "dac": BoardType("dac", _REFERENCE, "DAC8-REF", "docs/boards/dac.md",
                     driver="hal.adc_dac.dac:DacDriver", probe="hal.adc_dac.dac_regs:DAC_REGMAP"),
    "pio": BoardType("pio", _REFERENCE, "PIO24-REF", "docs/boards/pio.md",
                     driver="hal.pio.pio:PioDriver", probe="hal.pio.pio_regs:PIO_REGS"),
    "quad": BoardType("quad", _REFERENCE, "QUAD4-REF", "docs/boards/quadrature.md",
                      driver="hal.quadrature.quad:QuadratureDriver", probe="hal.quadrature.quad_regs:QUAD_REGS"),
    "bit3": BoardType("bit3", _REFERENCE, "BIT3-REF", "docs/boards/bit3.md",
                      driver="hal.bit3.driver:Bit3Driver", probe="hal.bit3.regs:BIT3_CSR"),
    "vmivme-4116": BoardType("dac", "VMIC", "VMIVME-4116", "docs/boards/vmivme4116.md",
                             driver="hal.adc_dac.vmivme4116:VmiVme4116Driver",
                             probe="hal.adc_dac.vmivme4116:probe_vmivme4116"),  # no ID register: reads the CSR
    # VMIC VMIVME-2536, 32 optically coupled inputs and outputs: a PIO without PWM; its BID value
    # is not published, so the probe checks that the registers answer (docs/boards/vmivme2536.md)
    "vmivme-2536": BoardType("pio", "VMIC", "VMIVME-2536", "docs/boards/vmivme2536.md",
                             driver="hal.pio.vmivme2536:Vmi2536Driver",
                             probe="hal.pio.vmivme2536:probe_vmivme2536"),
    # SBS (Bit 3) Model 617 PCI-to-VME adaptor, the vision link: no ID register in its PCI BARs,
    # so the probe reads what must read 0 (docs/boards/sbs617.md)
    "sbs617": BoardType("bit3", "SBS Technologies (Bit 3)", "Model 617 PCI-to-VME adaptor", "docs/boards/sbs617.md",
                        driver="hal.bit3.sbs617:Sbs617Driver", probe="hal.bit3.sbs617:probe_sbs617", bus="pci"),
    # VMIC VMIVME-3113A, 64-channel scanning 12-bit ADC: ID 0x1100 (docs/boards/vmivme-3113a.md)
    "vmivme-3113a": BoardType("adc", "VMIC", "VMIVME-3113A", "docs/boards/vmivme-3113a.md",
                              driver="hal.adc_dac.vmivme3113a:Vmivme3113aDriver",
                              probe="hal.adc_dac.vmivme3113a_regs:VMI3113A_REGMAP"),
    # RAM has no driver and no ID register: memory, read and written as bytes (the emulator's
    # RamBoard is the bus's test memory and the BIT3's dual-port memory). It is here so that
    # both tables name the same types and `crate list` can say what a RAM slot is.
    "ram": BoardType("ram", _REFERENCE, "RAM", "docs/vme.md"),
}


def _board_type(name: str, obj: Any) -> BoardType:
    if not isinstance(obj, BoardType):
        raise TypeError(f"a driver-side board type is a hal.board_types.BoardType, not {type(obj).__name__}")
    return obj


BOARD_TYPES: PluginTable[BoardType] = PluginTable("vmehil.board_drivers", "board type", BUILTIN_BOARD_TYPES,
                                                  _board_type)


def board_role(type_name: str) -> str | None:
    """The role of a board type (None: not a driver-side board type)."""
    bt = BOARD_TYPES.get(type_name)
    return bt.role if bt is not None else None


def types_answering(offset: int, width: Width, value: int) -> list[str]:
    """The board types whose ID register is at ``offset``, of ``width``, and reads ``value``:
    what a slot holds instead of the board the rig names. A type whose probe cannot be loaded is
    left out (it cannot be what answered)."""
    found = []
    for name in BOARD_TYPES.names():
        try:
            reg = BOARD_TYPES[name].id_register()
            if reg is not None and (reg.offset, reg.width, reg.reset) == (offset, width, value):
                found.append(name)
        except Exception:  # a broken plug-in must not hide the refusal being written
            continue
    return found
