"""Emulation of a BIT3 VME-to-VME adaptor (after the Bit 3 Model 412/413) and its link.

Three pieces:

* :class:`Bit3Link` — the cable and the remote crate's dual-port memory. Its storage is one
  buffer: a 64-byte *link header* (remote power and the doorbell counters: signals on the
  cable, not visible through the window) followed by the dual-port memory. The buffer is a
  ``bytearray`` in one process or a ``multiprocessing.shared_memory`` segment across
  processes (:meth:`Bit3Link.create_shared` / :meth:`Bit3Link.attach_shared`).
* :class:`Bit3Board` — the local card: the CSR block (:data:`CSR_MAP`) in A16;
  when installed in a crate it also installs its window board (:class:`Bit3WindowBoard`) in
  A24 or A32.
* :class:`Bit3RemotePort` — the remote (vision) computer's side: direct access to its own
  dual-port memory, remote power, ringing the local card and receiving its doorbells.

Link header (big-endian u32 words)::

    0x00 MAGIC            0x42495433 ("BIT3")
    0x04 VERSION          1
    0x08 MEM_SIZE         bytes of dual-port memory following the header
    0x0C REMOTE_POWER     1 while the remote crate is powered (the remote side sets it)
    0x10 BELL_REMOTE_CNT  doorbells rung by the local card (mod 2^32); code at 0x14
    0x18 BELL_LOCAL_CNT   doorbells rung by the remote side (mod 2^32); code at 0x1C

A doorbell writes its code, then increments the count; the receiver polls the count (and, in
one process, is also called back at once). Doorbells that arrive faster than they are polled
coalesce (the count says how many); the protocol never depends on them.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Sequence
from multiprocessing import resource_tracker, shared_memory
from typing import Any

from emulators.board import Board, BoardAccessError, RegisterBoard
from emulators.board_factory import BuildContext
from hal.config import ConfigTable
from hal.shm import BufferMemory
from hal.vme.errors import BusErrorCause
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width


# --- the card's CSR block, as docs/boards/bit3.md states it -----------------------------------
# Written from the doc's register table (not from the driver's map): fields as the doc's
# [msb:lsb], offsets and reset values as the doc's literals. The masks the card's logic uses
# below are taken from this declaration, which a test checks against the doc.
def _bits(name: str, msb: int, lsb: int | None = None) -> Field:
    low = msb if lsb is None else lsb
    return Field(name, low, msb - low + 1)


CARD_ID = 0x0413
CSR_MAP = RegisterMap(
    name="bit3",
    size=0x10,
    space=AddressSpace.A16,
    doc="BIT3 VME-to-VME adaptor, local CSR block (emulator's declaration, from docs/boards/bit3.md)",
    registers=(
        Register("STATUS", 0x00, Width.D16, Access.W1C, reset=0x0000, fields=(
            _bits("doorbell", 5), _bits("parity", 4), _bits("remote_berr", 3), _bits("timeout", 2),
            _bits("remote_power", 1), _bits("link_up", 0))),
        Register("COMMAND", 0x02, Width.D16, Access.RW, reset=0x0002, fields=(
            _bits("window_enable", 1), _bits("reset", 0))),
        Register("IRQ_CTRL", 0x04, Width.D16, Access.RW, reset=0x0000, fields=(
            _bits("vector", 15, 8), _bits("enable", 3), _bits("level", 2, 0))),
        Register("DOORBELL_OUT", 0x06, Width.D16, Access.WO),
        Register("DOORBELL_IN", 0x08, Width.D16, Access.RO, reset=0x0000),
        Register("DOORBELL_COUNT", 0x0A, Width.D16, Access.RO, reset=0x0000),
        Register("ERRORS", 0x0C, Width.D16, Access.RO, reset=0x0000),
        Register("ID", 0x0E, Width.D16, Access.RO, reset=CARD_ID),
    ),
)
_ST = {f.name: f.mask for f in CSR_MAP["STATUS"].fields}
_ST_LIVE = _ST["link_up"] | _ST["remote_power"]  # not stored: the cable and the remote power
_ST_STICKY = _ST["timeout"] | _ST["remote_berr"] | _ST["parity"]
_ST_W1C = _ST_STICKY | _ST["doorbell"]
_CMD = {f.name: f.mask for f in CSR_MAP["COMMAND"].fields}
_IRQ_LEVEL = CSR_MAP["IRQ_CTRL"].field("level")
_IRQ_ENABLE = CSR_MAP["IRQ_CTRL"].field("enable")
_IRQ_VECTOR = CSR_MAP["IRQ_CTRL"].field("vector")

LINK_MAGIC = 0x42495433
LINK_VERSION = 1
LINK_HEADER_SIZE = 0x40
_H_MAGIC, _H_VERSION, _H_SIZE, _H_POWER = 0x00, 0x04, 0x08, 0x0C
_H_BELL_REMOTE, _H_BELL_LOCAL = 0x10, 0x18  # count at +0, code at +4

DoorbellListener = Callable[[], None]
_CREATED_HERE: set[str] = set()  # segments this process created (and its tracker will unlink)


class Bit3Link:
    """The link: header + dual-port memory in one buffer.

    Args:
        mem_size: bytes of dual-port memory (the size of the window on the local card).
        buffer: storage of at least ``LINK_HEADER_SIZE + mem_size`` bytes (a new ``bytearray``
            by default); ``init=False`` attaches to an already formatted buffer.
    """

    def __init__(self, mem_size: int = 0x10000, buffer: Any = None, *, init: bool = True) -> None:
        if buffer is None:
            buffer = bytearray(LINK_HEADER_SIZE + mem_size)
        self._buf = memoryview(buffer).cast("B")
        self._shm: shared_memory.SharedMemory | None = None
        self._owner = False
        if init:
            if len(self._buf) < LINK_HEADER_SIZE + mem_size:
                raise ValueError(f"link buffer of {len(self._buf)} bytes is too small for {mem_size} bytes")
            self._buf[:LINK_HEADER_SIZE] = bytes(LINK_HEADER_SIZE)
            self._put(_H_SIZE, mem_size)
            self._put(_H_VERSION, LINK_VERSION)
            self._put(_H_MAGIC, LINK_MAGIC)
        else:
            if self._get(_H_MAGIC) != LINK_MAGIC or self._get(_H_VERSION) != LINK_VERSION:
                raise ValueError("buffer is not a formatted BIT3 link (magic/version mismatch)")
            mem_size = self._get(_H_SIZE)
        self.mem_size = mem_size
        self.mem = self._buf[LINK_HEADER_SIZE : LINK_HEADER_SIZE + mem_size]
        self._local_listeners: list[DoorbellListener] = []
        self._remote_listeners: list[DoorbellListener] = []

    # --- shared memory -------------------------------------------------------------------
    @classmethod
    def create_shared(cls, mem_size: int = 0x10000, name: str | None = None) -> Bit3Link:
        """Create a shared-memory segment and format it. The creator owns it: call
        :meth:`close` with ``unlink=True`` when done (also on failure)."""
        shm = shared_memory.SharedMemory(name=name, create=True, size=LINK_HEADER_SIZE + mem_size)
        try:
            link = cls(mem_size, shm.buf, init=True)
        except BaseException:
            shm.close()
            shm.unlink()
            raise
        link._shm, link._owner = shm, True
        _CREATED_HERE.add(shm.name)
        return link

    @classmethod
    def attach_shared(cls, name: str) -> Bit3Link:
        """Attach to a segment made by :meth:`create_shared` in another process. The attacher
        never unlinks it (and is removed from Python's resource tracker so it cannot)."""
        shm = shared_memory.SharedMemory(name=name, create=False)
        # Python < 3.13 registers attached segments with the resource tracker, which would
        # unlink the creator's segment when this (attaching) process exits.
        if shm.name not in _CREATED_HERE:
            try:
                resource_tracker.unregister(shm._name, "shared_memory")  # type: ignore[attr-defined]
            except Exception:  # pragma: no cover - tracker implementation detail
                pass
        try:
            link = cls(buffer=shm.buf, init=False)
        except BaseException:
            shm.close()
            raise
        link._shm = shm
        return link

    @property
    def shm_name(self) -> str | None:
        return self._shm.name if self._shm is not None else None

    def close(self, unlink: bool | None = None) -> None:
        """Unlink the segment if ``unlink`` (default: if owner), release the views, close it.

        The unlink happens first, so the segment is removed even if closing fails because
        views are still exported (release ``BufferMemory``/``Bit3RemotePort`` objects first)."""
        shm, self._shm = self._shm, None
        if shm is not None and (self._owner if unlink is None else unlink):
            try:
                shm.unlink()
            except FileNotFoundError:
                pass
            _CREATED_HERE.discard(shm.name)
        self.mem.release()
        self._buf.release()
        if shm is not None:
            try:
                shm.close()
            except BufferError as e:
                self._shm = shm  # keep it alive (and closable) while the views are in use
                raise BufferError(f"BIT3 link {shm.name}: views of the memory are still in use; "
                                  "release BufferMemory/Bit3RemotePort objects before close()") from e

    # --- header --------------------------------------------------------------------------
    def _get(self, off: int) -> int:
        return struct.unpack_from(">I", self._buf, off)[0]

    def _put(self, off: int, value: int) -> None:
        struct.pack_into(">I", self._buf, off, value & 0xFFFFFFFF)

    @property
    def remote_power(self) -> bool:
        """True while the remote crate is powered (set by the remote side)."""
        return self._get(_H_POWER) != 0

    @remote_power.setter
    def remote_power(self, on: bool) -> None:
        self._put(_H_POWER, 1 if on else 0)

    # --- doorbells -----------------------------------------------------------------------
    def ring_remote(self, code: int) -> None:
        """Local card → remote side."""
        self._ring(_H_BELL_REMOTE, code, self._remote_listeners)

    def ring_local(self, code: int) -> None:
        """Remote side → local card."""
        self._ring(_H_BELL_LOCAL, code, self._local_listeners)

    def _ring(self, off: int, code: int, listeners: list[DoorbellListener]) -> None:
        self._put(off + 4, code)
        self._put(off, self._get(off) + 1)
        for cb in list(listeners):
            cb()

    def bells_to_remote(self) -> tuple[int, int]:
        """(count, last code) of doorbells rung by the local card."""
        return self._get(_H_BELL_REMOTE), self._get(_H_BELL_REMOTE + 4)

    def bells_to_local(self) -> tuple[int, int]:
        """(count, last code) of doorbells rung by the remote side."""
        return self._get(_H_BELL_LOCAL), self._get(_H_BELL_LOCAL + 4)

    def add_local_listener(self, cb: DoorbellListener) -> None:
        self._local_listeners.append(cb)

    def add_remote_listener(self, cb: DoorbellListener) -> None:
        self._remote_listeners.append(cb)


class Bit3Board(RegisterBoard):
    """The local BIT3 card: CSR block in A16 plus a remote-memory window (installed on attach).

    Args:
        name: board name; the window board is named ``"<name>.window"``.
        link: the cable/remote memory (a new in-process :class:`Bit3Link` by default).
        window_base, window_space: where the window sits on the local bus (A24 or A32).
        window_size: bytes mapped (default: all of the link's dual-port memory).
        poll_period_s: how often (simulated time) the card polls the link header for remote
            doorbells; needed when the remote side is another process (``None``: only the
            in-process callback).
        interface_timeout_s: time a window cycle takes to fail when the link is down.
    """

    TYPE = "bit3"
    REGMAP = CSR_MAP
    irq_release = "rora"
    FAULTS = {  # noqa: RUF012
        "link_down": "cable unplugged: window cycles time out (BERR LINK_DOWN, STATUS.timeout)",
        "remote_berr": "the remote bus answers BERR (params: start, end byte offsets; default all)",
        "parity": "parity errors on the cable (params: count, default 1)",
    }

    def __init__(
        self,
        name: str,
        link: Bit3Link | None = None,
        *,
        window_base: int = 0x400000,
        window_space: AddressSpace | str = AddressSpace.A24,
        window_size: int | None = None,
        poll_period_s: float | None = None,
        interface_timeout_s: float = 32e-6,
    ) -> None:
        self.link = link if link is not None else Bit3Link()
        self._bells_seen = self.link.bells_to_local()[0]
        super().__init__(name)
        space = AddressSpace.parse(window_space)
        if space is AddressSpace.A16:
            raise ValueError(f"{name}: the BIT3 window must be in A24 or A32, not A16")
        size = self.link.mem_size if window_size is None else int(window_size)
        if not 0 < size <= self.link.mem_size:
            raise ValueError(f"{name}: window_size {size} exceeds the link's {self.link.mem_size} bytes")
        self.window = Bit3WindowBoard(f"{name}.window", self, size)
        self.window_base = int(window_base)
        self.window_space = space
        self.poll_period_ns = None if poll_period_s is None else max(1, round(poll_period_s * 1e9))
        self.interface_timeout_ns = round(interface_timeout_s * 1e9)
        self.link.add_local_listener(self.poll_doorbell)

    # --- crate hooks ---------------------------------------------------------------------
    def attach(self, crate: Any) -> None:
        super().attach(crate)
        crate.install(self.window, base=self.window_base, space=self.window_space)
        if self.poll_period_ns is not None:
            crate.clock.schedule_in(self.poll_period_ns, self._poll_event)

    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> Board:
        """Lane 0's card (with its window) when every lane's card is idle alike: the same
        registers, link memory and doorbells, no polling (a sweep's run never talks to the
        vision computer). A card in use has no lane form."""
        def state(b: Board) -> Any:
            if not isinstance(b, Bit3Board) or b.poll_period_ns is not None:
                return None
            return (dict(b.regs), bytes(b.link.mem), b.link.bells_to_local(), b.link.bells_to_remote(), b._bells_seen)

        if state(boards[0]) is None:
            raise NotImplementedError(f"board {boards[0].name!r} (bit3) polls its link: no lane form")
        return cls._adopt_passive(boards, state)

    def _poll_event(self) -> None:
        self.poll_doorbell()
        if self.crate is not None and self.poll_period_ns is not None:
            self.crate.clock.schedule_in(self.poll_period_ns, self._poll_event)

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "window": f"{self.window_space.name} 0x{self.window_base:X}",
                "window_size": self.window.size, "shm": self.link.shm_name or "-"}

    # --- status --------------------------------------------------------------------------
    @property
    def link_up(self) -> bool:
        return self.fault("link_down") is None and self.link.remote_power

    def read_STATUS(self) -> int:
        value = self.regs["STATUS"] & ~_ST_LIVE
        if self.link_up:
            value |= _ST["link_up"]
        if self.link.remote_power:
            value |= _ST["remote_power"]
        return value

    def write_STATUS(self, value: int) -> None:
        self.regs["STATUS"] &= ~(value & _ST_W1C)
        if value & _ST["doorbell"]:
            self.release_irq()

    def write_COMMAND(self, value: int) -> None:
        if value & _CMD["reset"]:
            self.regs["STATUS"] &= ~_ST_STICKY
            self.regs["ERRORS"] = 0
        self.regs["COMMAND"] = value & ~_CMD["reset"]  # the reset bit reads 0

    def write_IRQ_CTRL(self, value: int) -> None:
        self.regs["IRQ_CTRL"] = value
        self._update_irq()

    # --- doorbells -----------------------------------------------------------------------
    def write_DOORBELL_OUT(self, value: int) -> None:
        if not self.link_up:
            self._set_error(_ST["timeout"])
            raise BoardAccessError(BusErrorCause.LINK_DOWN, f"{self.name}: doorbell not delivered: {self._why_down()}")
        self.link.ring_remote(value)

    def read_DOORBELL_IN(self) -> int:
        self.regs["STATUS"] &= ~_ST["doorbell"]
        self.release_irq()
        return self.regs["DOORBELL_IN"]

    def poll_doorbell(self) -> None:
        """Latch doorbells the remote side has rung since the last poll (raises the IRQ)."""
        count, code = self.link.bells_to_local()
        if count == self._bells_seen:
            return
        new = (count - self._bells_seen) & 0xFFFFFFFF
        self._bells_seen = count
        if not self.link_up:
            return  # rung while the cable was out: lost, as on the real link
        self.regs["DOORBELL_IN"] = code & 0xFFFF
        self.regs["DOORBELL_COUNT"] = (self.regs["DOORBELL_COUNT"] + new) & 0xFFFF
        self.regs["STATUS"] |= _ST["doorbell"]
        self._update_irq()

    def _update_irq(self) -> None:
        ctrl = self.regs["IRQ_CTRL"]
        level = _IRQ_LEVEL.get(ctrl)
        if self.regs["STATUS"] & _ST["doorbell"] and _IRQ_ENABLE.get(ctrl) and level:
            self.request_irq(level, _IRQ_VECTOR.get(ctrl))
        elif self.irq_pending:
            self.release_irq()

    def reset(self) -> None:
        super().reset()
        if hasattr(self, "link"):
            self._bells_seen = self.link.bells_to_local()[0]

    # --- remote window -------------------------------------------------------------------
    def _count_error(self) -> None:
        self.regs["ERRORS"] = (self.regs["ERRORS"] + 1) & 0xFFFF

    def _set_error(self, bit: int) -> None:
        self.regs["STATUS"] |= bit
        self._count_error()

    def _why_down(self) -> str:
        if self.fault("link_down") is not None:
            return "link cable disconnected"
        return "remote crate power is off"

    def remote_cycle(self, offset: int, width: Width, value: int | None) -> int:
        """One window cycle at byte ``offset`` of the remote memory (read if ``value`` is None),
        checked in the doc's order (docs/boards/bit3.md, "Window cycles")."""
        if not self.regs["COMMAND"] & _CMD["window_enable"]:
            raise BoardAccessError(
                BusErrorCause.NO_RESPONDER, f"{self.name}: window disabled (COMMAND.window_enable=0)"
            )
        if not self.link_up:
            if self.crate is not None and self.interface_timeout_ns:
                self.crate.clock.advance(self.interface_timeout_ns)
            self._set_error(_ST["timeout"])
            raise BoardAccessError(BusErrorCause.LINK_DOWN, f"{self.name}: {self._why_down()}")
        if self.regs["STATUS"] & _ST_STICKY:
            self._count_error()
            raise BoardAccessError(
                BusErrorCause.LINK_DOWN,
                f"{self.name}: interface error latched (STATUS=0x{self.read_STATUS():04X}); reset the link",
            )
        parity = self.fault("parity")
        if parity is not None:
            left = int(parity.get("count", 1)) - 1
            if left > 0:
                parity["count"] = left
            else:
                self.clear_fault("parity")
            self._set_error(_ST["parity"])
            raise BoardAccessError(BusErrorCause.REMOTE, f"{self.name}: parity error on the link cable")
        berr = self.fault("remote_berr")
        if berr is not None and berr.get("start", 0) <= offset < berr.get("end", 1 << 32):
            self._set_error(_ST["remote_berr"])
            raise BoardAccessError(BusErrorCause.REMOTE, f"{self.name}: remote bus error at remote +0x{offset:X}")
        mem = self.link.mem
        n = int(width)
        if value is None:
            return int.from_bytes(mem[offset : offset + n], "big")
        mem[offset : offset + n] = value.to_bytes(n, "big")
        return 0


class Bit3WindowBoard(Board):
    """The BIT3 window on the local bus; every cycle goes to :meth:`Bit3Board.remote_cycle`."""

    TYPE = "bit3-window"
    access_ns = 1000  # a remote cycle crosses the cable and the remote bus

    def __init__(self, name: str, card: Bit3Board, size: int) -> None:
        super().__init__(name, size)
        self.card = card

    def bus_read(self, offset: int, width: Width) -> int:
        return self.card.remote_cycle(offset, width, None)

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        self.card.remote_cycle(offset, width, value)

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "card": self.card.name, "size": self.size}


class Bit3RemotePort:
    """The remote (vision) computer's side of the link.

    ``memory`` is a :class:`hal.shm.BufferMemory` over the dual-port memory (the
    remote computer accesses its own memory directly; it never fails). Doorbells from the
    local card are counted by :meth:`poll_doorbells` and, in one process, also delivered to
    callbacks registered with :meth:`on_doorbell`.
    """

    def __init__(self, link: Bit3Link) -> None:
        self.link = link
        self.memory = BufferMemory(link.mem)
        self._seen = link.bells_to_remote()[0]
        self._callbacks: list[Callable[[int], None]] = []
        link.add_remote_listener(self._deliver)

    def power_on(self) -> None:
        self.link.remote_power = True

    def power_off(self) -> None:
        self.link.remote_power = False

    def ring(self, code: int = 1) -> None:
        """Ring the local card's doorbell (its IRQ, if enabled)."""
        self.link.ring_local(code & 0xFFFF)

    def on_doorbell(self, callback: Callable[[int], None]) -> None:
        """Call ``callback(code)`` for doorbells from the local card (in-process delivery)."""
        self._callbacks.append(callback)

    def poll_doorbells(self) -> tuple[int, int]:
        """(number of new doorbells since the last poll, last code)."""
        count, code = self.link.bells_to_remote()
        new = (count - self._seen) & 0xFFFFFFFF
        self._seen = count
        return new, code

    def _deliver(self) -> None:
        new, code = self.poll_doorbells()
        if new:
            for cb in list(self._callbacks):
                cb(code)

    def close(self) -> None:
        self.memory.release()


def bit3_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> Bit3Board:
    """Crate-file factory for ``type = "bit3"``.

    Keys (besides the common ones, which place the CSR block in A16): ``window_space``
    ("A24"/"A32", default "A24"), ``window_base``, ``window_size`` (bytes, default 0x10000),
    ``shm`` (attach to a shared-memory link created by another process; default: an
    in-process link with the remote crate powered), ``poll_period_us`` (default 50 with
    ``shm``).
    """
    window_space = cfg.get_str("window_space", "A24", choices=("A24", "A32"))
    window_base = cfg.get_int("window_base", min=0, max=(1 << 32) - 1)
    window_size = cfg.get_int("window_size", 0x10000, min=4, max=1 << 28)
    shm = cfg.get_str("shm", "")
    if shm:
        link = Bit3Link.attach_shared(shm)
        poll_us = cfg.get_float("poll_period_us", 50.0, min=1.0, max=1e6)
    else:
        link = Bit3Link(window_size)
        link.remote_power = True
        poll_us = cfg.get_float("poll_period_us", 0.0, min=0.0, max=1e6)
    return Bit3Board(name, link, window_base=window_base, window_space=window_space,
                     window_size=window_size if window_size <= link.mem_size else None,
                     poll_period_s=poll_us * 1e-6 if poll_us else None)
