"""Driver for the SBS (Bit 3) Model 617 PCI-to-VME adaptor as the robot's vision link.

The robot's host holds the PCI local card; the vision computer's VME crate holds the remote
card, and the vision computer's memory is read and written through the card's window
(docs/boards/sbs617.md). The card never fails the host's cycle: a remote access that went wrong
latches a bit in LOC_STATUS. So every transfer ends with a read of LOC_STATUS, and a set error
bit is cleared (LOC_CMD1.CLR_ERROR) and raised as :class:`LinkDownError` or
:class:`RemoteBusError` — the check both public drivers make after a transfer.

The public interface is :class:`hal.bit3.Bit3Driver`'s, so ``hal.bit3.protocol`` runs on either.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from hal.bit3.driver import Bit3WindowMemory
from hal.bit3.errors import Bit3Error, LinkDownError, RemoteBusError
from hal.bit3.sbs617_regs import (
    AM_A24_DATA,
    AM_A32_DATA,
    FUNCTION_REMOTE_RAM,
    LSR_LATCHED,
    LSR_NOT_USABLE,
    PAGE_SIZE,
    SBS617_MAP_ENTRY,
    SBS617_NODE,
    WINDOW_SIZE,
)
from hal.board_types import ProbeReading
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BusError, VmeError
from hal.vme.types import AddressSpace, Width, resolve_am
from hal.vme.window import BoardWindow

_LSR = SBS617_NODE["LOC_STATUS"]
_CMD1 = SBS617_NODE["LOC_CMD1"]
_REM_CMD1 = SBS617_NODE["REM_CMD1_STATUS"]
_INT_CTRL = SBS617_NODE["LOC_INT_CTRL"]
_ENTRY = SBS617_MAP_ENTRY["PCI_VME_MAP"]
_CLEAR_ERRORS = _CMD1.pack(CLR_ERROR=1)
_CLEAR_PR = _CMD1.pack(CLR_PR_INT=1)
_PR_INT = _LSR.field("PR_INT").mask
_DATA_AM = {AddressSpace.A24: AM_A24_DATA, AddressSpace.A32: AM_A32_DATA}


@dataclass(frozen=True)
class Sbs617Status:
    """LOC_STATUS, decoded; ``errors``: link errors this driver has seen (the card counts none)."""

    raw: int
    link_up: bool
    timeout: bool
    remote_berr: bool
    parity: bool
    lrc: bool
    doorbell: bool
    errors: int

    @property
    def remote_power(self) -> bool:
        """NO_CONNECT covers both "remote power off" and "cable out": the card cannot tell them apart."""
        return self.link_up

    @property
    def error_latched(self) -> bool:
        return bool(self.raw & LSR_LATCHED)

    @property
    def usable(self) -> bool:
        return not self.raw & LSR_NOT_USABLE


class Sbs617Driver:
    """Local-side driver of a Model 617 (node registers, mapping RAM and window on ``bus``).

    Args:
        bus: the host's bus; the three BARs are in ``bar_space`` (A32) at the given bases.
        node_base, map_base, window_base: BAR 1 (node registers), BAR 2 (mapping RAM), BAR 3.
        remote_base, remote_space: where the vision computer's memory is on its VME bus.
        mem_size: bytes of it the window maps (from page 0 of the window).
        irq_level, irq_vector: how the host's interrupt line is delivered (crate file).
    """

    def __init__(
        self,
        bus: VmeBus,
        node_base: int,
        map_base: int,
        window_base: int,
        *,
        remote_base: int,
        remote_space: SpaceLike = "A24",
        mem_size: int = 0x1000,
        bar_space: SpaceLike = "A32",
        irq_level: int = 3,
        irq_vector: int = 0xB3,
    ) -> None:
        self.bus = bus
        self.node = BoardWindow(bus, node_base, SBS617_NODE, bar_space)
        self.maps = BoardWindow(bus, map_base, SBS617_MAP_ENTRY, bar_space)
        self.window_base = window_base
        self.window_am = resolve_am(bar_space)
        space = resolve_am(remote_space).space
        if space not in _DATA_AM:
            raise ValueError(f"the remote memory must be in A24 or A32, not {space.name}")
        self.remote_am = _DATA_AM[space]
        if remote_base % PAGE_SIZE or not 0 < mem_size <= WINDOW_SIZE:
            raise ValueError(f"remote base 0x{remote_base:X} must be 4 KiB aligned and 0 < mem_size <= 32 MiB")
        self.remote_base = remote_base
        self.window_size = int(mem_size)
        if not 1 <= irq_level <= 7 or not 0 <= irq_vector <= 0xFF:
            raise ValueError(f"IRQ level {irq_level} must be 1..7 and vector {irq_vector} 0..255")
        self.irq_level = irq_level
        self.irq_vector = irq_vector
        self.errors = 0
        self._doorbell_cb: Callable[[int], None] | None = None

    # --- card ----------------------------------------------------------------------------
    def _decode(self, raw: int) -> Sbs617Status:
        f = _LSR.unpack(raw)
        return Sbs617Status(raw, not f["NO_CONNECT"], bool(f["TIMEOUT_ERR"]), bool(f["REMBUS_ERR"]),
                            bool(f["PARITY_ERR"]), bool(f["LRC_ERR"]), bool(f["PR_INT"]), self.errors)

    def status(self) -> Sbs617Status:
        """Read and decode LOC_STATUS."""
        return self._decode(self.node.read("LOC_STATUS"))

    def reset_link(self) -> Sbs617Status:
        """The reset sequence (NetBSD ``b3_617_reset``): check the connection, read the remote
        status (discarded: it clears the power-on transition), clear the latched errors, read the
        status again. Returns it; ``.usable`` says whether the link now works."""
        st = self.status()
        if not st.link_up:
            return st
        self.node.read("REM_CMD1_STATUS")
        self.node.write("LOC_CMD1", _CLEAR_ERRORS)
        return self.status()

    def probe(self) -> Sbs617Status:
        """The reset sequence; raises :class:`LinkDownError` (remote off / cable out) or
        :class:`Bit3Error` (an interface error that clearing did not remove). The card has no
        ID register readable through its BARs (its PCI IDs are in configuration space)."""
        st = self.reset_link()
        if not st.link_up:
            raise LinkDownError(f"SBS 617 at 0x{self.node.base:X}: not connected (LOC_STATUS=0x{st.raw:02X}): "
                                "the remote crate is off or the cable is out", None, st.raw)
        if not st.usable:
            raise Bit3Error(f"SBS 617 at 0x{self.node.base:X}: interface error after reset "
                            f"(LOC_STATUS=0x{st.raw:02X})")
        return st

    def setup(self) -> Sbs617Status:
        """Probe, then map the window: PCI->VME entry i = remote page i (remote RAM, data AM, no swap)."""
        st = self.probe()
        for i in range(-(-self.window_size // PAGE_SIZE)):
            entry = _ENTRY.pack(VME_PAGE=(self.remote_base // PAGE_SIZE) + i, AM=self.remote_am,
                                FUNCTION=FUNCTION_REMOTE_RAM)
            self.maps.write_offset(4 * i, entry, Width.D32)
        return st

    # --- errors --------------------------------------------------------------------------
    def _check(self, what: str) -> None:
        """After a transfer: read LOC_STATUS; on an error clear it and raise."""
        raw = self.node.read("LOC_STATUS")
        if not raw & LSR_NOT_USABLE:
            return
        if raw & LSR_LATCHED:
            self.node.write("LOC_CMD1", _CLEAR_ERRORS)
        self.errors += 1
        f = _LSR.unpack(raw)
        state = (f"LOC_STATUS=0x{raw:02X} no_connect={f['NO_CONNECT']} timeout={f['TIMEOUT_ERR']} "
                 f"rembus={f['REMBUS_ERR']} parity={f['PARITY_ERR']} lrc={f['LRC_ERR']}")
        if f["NO_CONNECT"] or f["TIMEOUT_ERR"]:
            raise LinkDownError(f"SBS 617 {what}: link down ({state}); check the cable and the remote "
                                "crate's power, then reset_link()", None, raw)
        raise RemoteBusError(f"SBS 617 {what}: remote bus error ({state}); the error is cleared", None, raw)

    def _bus_failed(self, e: BusError, what: str) -> LinkDownError:
        return LinkDownError(f"SBS 617 {what}: the host's bus failed ({e}); is the card there?", e, None)

    def _check_range(self, offset: int, nbytes: int) -> None:
        if offset < 0 or offset + nbytes > self.window_size:
            raise ValueError(f"window access {offset:#x}..{offset + nbytes:#x} outside the "
                             f"{self.window_size:#x}-byte memory")

    # --- window --------------------------------------------------------------------------
    def _read(self, offset: int, width: Width) -> int:
        return self.bus.read(self.window_base + offset, space=self.window_am, width=width)

    def _write(self, offset: int, value: int, width: Width) -> None:
        self.bus.write(self.window_base + offset, value, space=self.window_am, width=width)

    def read(self, offset: int, width: Width = Width.D32) -> int:
        """Read one big-endian value at byte ``offset`` of the remote memory (then the status check)."""
        self._check_range(offset, int(width))
        try:
            value = self._read(offset, width)
        except BusError as e:
            raise self._bus_failed(e, f"read +0x{offset:X}") from e
        self._check(f"read +0x{offset:X}")
        return value

    def write(self, offset: int, value: int, width: Width = Width.D32) -> None:
        self._check_range(offset, int(width))
        try:
            self._write(offset, value, width)
        except BusError as e:
            raise self._bus_failed(e, f"write +0x{offset:X}") from e
        self._check(f"write +0x{offset:X}")

    def read_bytes(self, offset: int, size: int) -> bytes:
        """``size`` bytes: D8 cycles to a 4-byte boundary, D32 single cycles, D8 for the rest;
        then one status check for the whole transfer."""
        self._check_range(offset, size)
        out = bytearray()
        head = min(size, (-offset) % 4)
        words = (size - head) // 4
        try:
            out += bytes(self._read(offset + i, Width.D8) for i in range(head))
            for k in range(words):
                out += self._read(offset + head + 4 * k, Width.D32).to_bytes(4, "big")
            start = offset + head + 4 * words
            out += bytes(self._read(start + i, Width.D8) for i in range(size - head - 4 * words))
        except BusError as e:
            raise self._bus_failed(e, f"read +0x{offset:X}") from e
        self._check(f"read +0x{offset:X}..+0x{offset + size:X}")
        return bytes(out)

    def write_bytes(self, offset: int, data: bytes) -> None:
        size = len(data)
        self._check_range(offset, size)
        head = min(size, (-offset) % 4)
        words = (size - head) // 4
        try:
            for i in range(head):
                self._write(offset + i, data[i], Width.D8)
            for k in range(words):
                at = head + 4 * k
                self._write(offset + at, int.from_bytes(data[at:at + 4], "big"), Width.D32)
            for i in range(head + 4 * words, size):
                self._write(offset + i, data[i], Width.D8)
        except BusError as e:
            raise self._bus_failed(e, f"write +0x{offset:X}") from e
        self._check(f"write +0x{offset:X}..+0x{offset + size:X}")

    def memory(self, offset: int = 0, size: int | None = None) -> Sbs617WindowMemory:
        """A :class:`hal.shm.Memory` view of (part of) the remote memory for the protocol."""
        return Sbs617WindowMemory(self, offset, self.window_size - offset if size is None else size)

    # --- programmed interrupts -----------------------------------------------------------
    def ring_doorbell(self, code: int = 1) -> None:
        """Send the PR interrupt to the remote side (REM_CMD1.SND_PR). The card carries no
        code; ``code`` is accepted for the protocol's interface. Raises :class:`LinkDownError`
        when the remote card does not answer."""
        try:
            self.node.write("REM_CMD1_STATUS", _REM_CMD1.pack(SND_PR=1))
        except BusError as e:
            raise self._bus_failed(e, "ring") from e
        self._check("ring")

    def on_doorbell(self, callback: Callable[[int], None]) -> None:
        """Call ``callback(0)`` from the interrupt handler when the remote side interrupts;
        registers the handler at ``irq_vector`` and sets LOC_INT_CTRL.INT_EN."""
        self._doorbell_cb = callback
        if self.bus.irq_handler(self.irq_vector) is None:
            self.bus.register_irq_handler(self.irq_vector, self._irq)
        self.node.write("LOC_INT_CTRL", _INT_CTRL.pack(INT_EN=1))

    def disable_doorbell_irq(self) -> None:
        self.node.write("LOC_INT_CTRL", 0)
        self.bus.unregister_irq_handler(self.irq_vector)
        self._doorbell_cb = None

    def read_doorbell(self) -> int | None:
        """Poll: 0 if the remote side has interrupted (acknowledging it), else ``None``."""
        if not self.node.read("LOC_STATUS") & _PR_INT:
            return None
        self.node.write("LOC_CMD1", _CLEAR_PR)
        return 0

    def _irq(self, vector: int) -> None:
        raw = self.node.read("LOC_STATUS")
        if raw & LSR_LATCHED:
            # only with ERR_INT_EN, which this driver leaves off; clear so the line drops
            self.node.write("LOC_CMD1", _CLEAR_ERRORS)
        if raw & _PR_INT:
            self.node.write("LOC_CMD1", _CLEAR_PR)
            if self._doorbell_cb is not None:
                self._doorbell_cb(0)


#: the 617's window as :class:`hal.shm.Memory`: the one window memory of the vision link's cards
Sbs617WindowMemory = Bit3WindowMemory


def probe_sbs617(bus: VmeBus, base: int, space: AddressSpace) -> ProbeReading:
    """The dry pass's look at a 617 (reads only). The card has no ID register in its BARs (its PCI
    IDs are in configuration space), so this reads what the doc says must read 0 — LOC_STATUS bit
    3 and LOC_INT_CTRL bits 4:3 — and says whether the remote crate answers (NO_CONNECT)."""
    lsr_reg, ctrl_reg = SBS617_NODE["LOC_STATUS"], SBS617_NODE["LOC_INT_CTRL"]
    try:
        lsr = bus.read(base + lsr_reg.offset, space=space, width=lsr_reg.width)
        ctrl = bus.read(base + ctrl_reg.offset, space=space, width=ctrl_reg.width)
    except VmeError as e:
        # the card is gone (or its BARs are not where the rig file says); the real-bus dry pass
        # never gets here: it refuses the card unread (its BARs are PCI memory, docs/vme-user.md)
        return ProbeReading(False, f"{type(e).__name__}: {e} (the SBS 617 is a PCI card: its registers are "
                                   "the host's PCI BARs, not VME addresses)")
    if lsr & 0x08 or ctrl & 0x18:
        return ProbeReading(False, f"LOC_STATUS 0x{lsr:02X}, LOC_INT_CTRL 0x{ctrl:02X}: "
                                   "bits the 617 reads as 0 are set")
    remote = "remote crate off or cable out" if lsr & _LSR.field("NO_CONNECT").mask else "remote connected"
    return ProbeReading(True, f"LOC_STATUS 0x{lsr:02X} ({remote}), LOC_INT_CTRL 0x{ctrl:02X}; no ID register")
