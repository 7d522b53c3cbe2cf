"""Driver for the BIT3 VME-to-VME adaptor: link status, remote window, doorbells.

The driver sees the card as two windows on its bus: the CSR block (:data:`BIT3_CSR`, A16 by
default) and the remote-memory window (A24 or A32). Window accesses that fail on the link
raise :class:`LinkDownError` (link down, remote crate off, or a latched interface error) or
:class:`RemoteBusError` (the remote bus or the cable answered BERR/parity); after such an
error the card refuses remote cycles until :meth:`Bit3Driver.reset_link`.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from hal.bit3.errors import Bit3Error, LinkDownError, RemoteBusError
from hal.bit3.regs import BIT3_CSR, CARD_ID
from hal.vme.bus import SpaceLike, VmeBus
from hal.vme.errors import BusError, BusErrorCause
from hal.vme.types import AddressSpace, Width, resolve_am
from hal.vme.window import BoardWindow


@dataclass(frozen=True)
class Bit3Status:
    """Decoded STATUS register (plus the ERRORS counter)."""

    raw: int
    link_up: bool
    remote_power: bool
    timeout: bool
    remote_berr: bool
    parity: bool
    doorbell: bool
    errors: int

    @property
    def error_latched(self) -> bool:
        """A sticky interface error blocks the window until :meth:`Bit3Driver.reset_link`."""
        return self.timeout or self.remote_berr or self.parity

    @property
    def usable(self) -> bool:
        return self.link_up and not self.error_latched


class Bit3Driver:
    """Local-side driver of a BIT3 card.

    Args:
        bus: the VME bus.
        csr_base: base address of the CSR block in ``csr_space``.
        window_base: base address of the remote-memory window in ``window_space``.
        window_size: bytes mapped by the window.
        irq_level, irq_vector: used by :meth:`on_doorbell` for the incoming doorbell.
    """

    def __init__(
        self,
        bus: VmeBus,
        csr_base: int,
        window_base: int,
        *,
        csr_space: SpaceLike = "A16",
        window_space: SpaceLike = "A24",
        window_size: int = 0x10000,
        irq_level: int = 3,
        irq_vector: int = 0xB3,
    ) -> None:
        self.bus = bus
        self.csr = BoardWindow(bus, csr_base, BIT3_CSR, csr_space)
        self.window_base = window_base
        self.window_am = resolve_am(window_space)
        if self.window_am.space is AddressSpace.A16:
            raise ValueError("the BIT3 window must be in A24 or A32")
        self.window_size = int(window_size)
        if not 1 <= irq_level <= 7 or not 0 <= irq_vector <= 0xFF:
            raise ValueError(f"IRQ level {irq_level} must be 1..7 and vector {irq_vector} 0..255")
        self.irq_level = irq_level
        self.irq_vector = irq_vector
        self._doorbell_cb: Callable[[int], None] | None = None

    # --- card ----------------------------------------------------------------------------
    def probe(self) -> int:
        """Read the ID register; raise :class:`Bit3Error` if the card is not a BIT3."""
        card_id = self.csr.read("ID")
        if card_id != CARD_ID:
            raise Bit3Error(f"no BIT3 card at 0x{self.csr.base:X}: ID reads 0x{card_id:04X}, expected 0x{CARD_ID:04X}")
        return card_id

    def status(self) -> Bit3Status:
        """Read and decode STATUS (and ERRORS)."""
        raw = self.csr.read("STATUS")
        f = BIT3_CSR["STATUS"].unpack(raw)
        return Bit3Status(raw, bool(f["link_up"]), bool(f["remote_power"]), bool(f["timeout"]),
                          bool(f["remote_berr"]), bool(f["parity"]), bool(f["doorbell"]), self.csr.read("ERRORS"))

    def reset_link(self) -> Bit3Status:
        """Reset the link interface (clears the sticky errors); returns the new status.
        The link works again only if ``status.link_up`` (cable in, remote powered)."""
        self.csr.write("COMMAND", BIT3_CSR["COMMAND"].pack(reset=1, window_enable=1))
        return self.status()

    # --- window --------------------------------------------------------------------------
    def _check_range(self, offset: int, nbytes: int) -> None:
        if offset < 0 or offset + nbytes > self.window_size:
            raise ValueError(
                f"window access {offset:#x}..{offset + nbytes:#x} outside the {self.window_size:#x}-byte window"
            )

    def _translate(self, e: BusError) -> Bit3Error | BusError:
        try:
            st = self.status()
            raw: int | None = st.raw
            state = (f"STATUS=0x{st.raw:04X} link_up={int(st.link_up)} remote_power={int(st.remote_power)} "
                     f"timeout={int(st.timeout)} remote_berr={int(st.remote_berr)} parity={int(st.parity)}")
        except BusError:
            raw, state = None, "STATUS unreadable"
        where = f"BIT3 window +0x{e.address - self.window_base:X}"
        if e.cause in (BusErrorCause.LINK_DOWN, BusErrorCause.NO_RESPONDER):
            return LinkDownError(f"{where}: link down ({e.detail or e.cause.value}; {state}); "
                                 "check cable and remote power, then reset_link()", e, raw)
        if e.cause is BusErrorCause.REMOTE:
            return RemoteBusError(f"{where}: remote bus error ({e.detail or e.cause.value}; {state}); "
                                  "reset_link() clears the latched error", e, raw)
        return e

    def read(self, offset: int, width: Width = Width.D32) -> int:
        """Read one big-endian value at byte ``offset`` of the remote memory."""
        self._check_range(offset, int(width))
        try:
            return self.bus.read(self.window_base + offset, space=self.window_am, width=width)
        except BusError as e:
            raise self._translate(e) from e

    def write(self, offset: int, value: int, width: Width = Width.D32) -> None:
        self._check_range(offset, int(width))
        try:
            self.bus.write(self.window_base + offset, value, space=self.window_am, width=width)
        except BusError as e:
            raise self._translate(e) from e

    def read_block(self, offset: int, count: int, width: Width = Width.D32) -> list[int]:
        """Block (BLT) read of ``count`` values."""
        self._check_range(offset, count * int(width))
        try:
            return self.bus.read_block(self.window_base + offset, count, space=self.window_am, width=width)
        except BusError as e:
            raise self._translate(e) from e

    def write_block(self, offset: int, values: Sequence[int], width: Width = Width.D32) -> None:
        self._check_range(offset, len(values) * int(width))
        try:
            self.bus.write_block(self.window_base + offset, values, space=self.window_am, width=width)
        except BusError as e:
            raise self._translate(e) from e

    def read_bytes(self, offset: int, size: int) -> bytes:
        """Read ``size`` bytes: D32 block cycles where aligned, D8 cycles at ragged ends."""
        out = bytearray()
        head = min(size, (-offset) % 4)
        out += bytes(self.read(offset + i, Width.D8) for i in range(head))
        words = (size - head) // 4
        if words:
            for v in self.read_block(offset + head, words, Width.D32):
                out += v.to_bytes(4, "big")
        start = offset + head + 4 * words
        out += bytes(self.read(start + i, Width.D8) for i in range(size - head - 4 * words))
        return bytes(out)

    def write_bytes(self, offset: int, data: bytes) -> None:
        """Write ``data``: D32 block cycles where aligned, D8 cycles at ragged ends."""
        size = len(data)
        head = min(size, (-offset) % 4)
        for i in range(head):
            self.write(offset + i, data[i], Width.D8)
        words = (size - head) // 4
        if words:
            vals = [int.from_bytes(data[head + 4 * i : head + 4 * i + 4], "big") for i in range(words)]
            self.write_block(offset + head, vals, Width.D32)
        for i in range(head + 4 * words, size):
            self.write(offset + i, data[i], Width.D8)

    def memory(self, offset: int = 0, size: int | None = None) -> Bit3WindowMemory:
        """A :class:`hal.shm.Memory` view of (part of) the window for the protocol."""
        return Bit3WindowMemory(self, offset, self.window_size - offset if size is None else size)

    # --- doorbells -----------------------------------------------------------------------
    def ring_doorbell(self, code: int = 1) -> None:
        """Ring the remote side (16-bit ``code``). Raises :class:`LinkDownError` if the link is down."""
        try:
            self.csr.write("DOORBELL_OUT", code & 0xFFFF)
        except BusError as e:
            raise self._translate(e) from e

    def on_doorbell(self, callback: Callable[[int], None]) -> None:
        """Call ``callback(code)`` from the interrupt handler when the remote side rings.
        Registers the handler at ``irq_vector`` and enables the doorbell IRQ at ``irq_level``."""
        self._doorbell_cb = callback
        if self.bus.irq_handler(self.irq_vector) is None:
            self.bus.register_irq_handler(self.irq_vector, self._irq)
        self.csr.write("IRQ_CTRL", BIT3_CSR["IRQ_CTRL"].pack(level=self.irq_level, enable=1, vector=self.irq_vector))

    def disable_doorbell_irq(self) -> None:
        self.csr.write("IRQ_CTRL", 0)
        self.bus.unregister_irq_handler(self.irq_vector)
        self._doorbell_cb = None

    def read_doorbell(self) -> int | None:
        """Poll: the pending doorbell code (acknowledging it), or ``None``."""
        if not self.status().doorbell:
            return None
        return self.csr.read("DOORBELL_IN")

    def _irq(self, vector: int) -> None:
        code = self.csr.read("DOORBELL_IN")  # acknowledges (RORA release)
        if self._doorbell_cb is not None:
            self._doorbell_cb(code)


class WindowDriver(Protocol):
    """What :class:`Bit3WindowMemory` needs of a vision-link card's driver (the reference BIT3's
    and the SBS 617's both have it)."""

    window_size: int

    def read_bytes(self, offset: int, size: int) -> bytes: ...

    def write_bytes(self, offset: int, data: bytes) -> None: ...


class Bit3WindowMemory:
    """:class:`hal.shm.Memory` through a vision-link card's window (the reference BIT3's or the
    SBS 617's, whose name for it is ``Sbs617WindowMemory``); raises ``Bit3Error`` on link failure."""

    def __init__(self, driver: WindowDriver, offset: int = 0, size: int | None = None) -> None:
        self.driver = driver
        self.base = offset
        self.size = driver.window_size - offset if size is None else size

    def read(self, offset: int, size: int) -> bytes:
        return self.driver.read_bytes(self.base + offset, size)

    def write(self, offset: int, data: bytes) -> None:
        self.driver.write_bytes(self.base + offset, data)
