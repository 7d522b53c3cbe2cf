"""Emulation of the SBS (Bit 3) Model 617 PCI-to-VME adaptor, written from docs/boards/sbs617.md.

The robot's host holds the PCI local card; the vision computer's VME crate holds the remote card.
In the emulated crate the card's three memory BARs stand in the host's A32 space:

* :class:`Sbs617Card` — the 32 node registers (BAR 1), a :class:`RegisterBoard` on this module's
  own declaration :data:`NODE_MAP` (literal, from the doc's table; not the driver's);
* :class:`Sbs617MapRam` — the 64 KiB mapping RAM (BAR 2), D32 entries;
* :class:`Sbs617Window` — the 32 MiB window (BAR 3): page *i* goes through PCI→VME entry *i* to
  the remote bus, where the vision computer's memory answers.

The cable and the remote crate are :class:`emulators.bit3.Bit3Link` (remote power, the vision
computer's memory, the programmed interrupts as its doorbell counters), so the emulated vision
computer runs unchanged against this card.

What the card does on a failed remote access is the doc's: the host's cycle completes (a read
returns all ones, a write is lost) and a LOC_STATUS bit latches — the driver must look.

Lanes (batched lockstep, :mod:`hal.lanes`): a sweep's run never talks to the vision computer, so
:meth:`Sbs617Card.from_lanes` takes lane 0's card itself, with its mapping RAM and window, when
every lane's card is idle alike (``Board._adopt_passive``); a card in use has no lane form.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import partial
from typing import Any

from emulators.bit3 import Bit3Link
from emulators.board import Board, BoardAccessError, RegisterBoard
from emulators.board_factory import BuildContext
from hal.config import ConfigTable
from hal.vme.errors import BusErrorCause
from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

# --- the node registers, as the doc's table states them --------------------------------------
# (name, offset, access, reset, fields as (name, msb, lsb)) — every register one byte.
_NODE_TABLE: tuple[tuple[str, int, Access, int, tuple[tuple[str, int, int], ...]], ...] = (
    ("LOC_CMD1", 0x00, Access.RW, 0x00, (("CLR_ERROR", 7, 7), ("CLR_PR_INT", 6, 6), ("SND_PT_INT", 5, 5))),
    ("LOC_INT_CTRL", 0x01, Access.RW, 0x00, (("INT_ACT", 7, 7), ("INT_EN", 6, 6), ("ERR_INT_EN", 5, 5),
                                             ("PT_CINT_SEL", 2, 0))),
    ("LOC_STATUS", 0x02, Access.RO, 0x00, (("PARITY_ERR", 7, 7), ("REMBUS_ERR", 6, 6), ("PR_INT", 5, 5),
                                           ("CARD_RDY", 4, 4), ("TIMEOUT_ERR", 2, 2), ("LRC_ERR", 1, 1),
                                           ("NO_CONNECT", 0, 0))),
    ("LOC_INT_STATUS", 0x03, Access.RO, 0x00, (("CINT", 7, 1),)),
    ("PCI_CONTROL", 0x04, Access.RW, 0x00, ()),
    ("REM_CMD1_STATUS", 0x08, Access.RW, 0x00, (
        ("RESET", 7, 7), ("CLR_PT", 6, 6), ("SND_PR", 5, 5), ("LOCK_BUS", 4, 4), ("PG_SEL", 3, 3),
        ("IACK_LEVEL", 2, 0), ("WAS_RESET", 7, 7), ("IACK_A1", 6, 6), ("PR_SET", 5, 5), ("NOT_LOCKED", 4, 4),
        ("PG_MODE", 3, 3), ("IACK_A2", 2, 2), ("PT_SET", 1, 1), ("IACK_A0", 0, 0))),
    ("REM_CMD2", 0x09, Access.RW, 0x00, (("DMA_PAUSE", 7, 7), ("AMOD_SEL", 6, 6), ("DMA_BLK", 5, 5),
                                         ("CINT_DIS", 4, 4), ("PG_SIZE", 3, 0))),
    ("REM_PAGE_LO", 0x0A, Access.RW, 0x00, ()),
    ("REM_PAGE_HI", 0x0B, Access.RW, 0x00, ()),
    ("REM_CARD_ID", 0x0C, Access.RW, 0x00, ()),
    ("REM_AMOD", 0x0D, Access.RW, 0x00, ()),
    ("REM_IACK", 0x0E, Access.RO, 0x00, ()),
    ("REM_IACK_BYTE", 0x0F, Access.RO, 0x00, ()),
    ("LDMA_CMD", 0x10, Access.RW, 0x00, (("START", 7, 7), ("DP_SEL", 6, 6), ("WRITE_SEL", 5, 5), ("D32_SEL", 4, 4),
                                         ("INT_EN", 2, 2), ("DONE", 1, 1), ("ACTIVE", 0, 0))),
    ("LDMA_RMD_CNT", 0x11, Access.RW, 0x00, ()),
    ("LDMA_PKT_CNT_LO", 0x12, Access.RW, 0x00, ()),
    ("LDMA_PKT_CNT_HI", 0x13, Access.RW, 0x00, ()),
    ("LDMA_ADDR_LO", 0x14, Access.RW, 0x00, ()),
    ("LDMA_ADDR_MID", 0x15, Access.RW, 0x00, ()),
    ("LDMA_ADDR_HI", 0x16, Access.RW, 0x00, ()),
    ("RDMA_LEN_CNT", 0x18, Access.RW, 0x00, ()),
    ("RDMA_ADDR_A23", 0x1A, Access.RW, 0x00, ()),
    ("RDMA_ADDR_A31", 0x1B, Access.RW, 0x00, ()),
    ("RDMA_ADDR_A7", 0x1C, Access.RW, 0x00, ()),
    ("RDMA_ADDR_A15", 0x1D, Access.RW, 0x00, ()),
    ("REM_SLAVE_STATUS", 0x1F, Access.RO, 0x00, (("PARITY_ERR", 7, 7), ("REMBUS_ERR", 6, 6), ("PR_SET", 5, 5),
                                                 ("TIMEOUT_ERR", 2, 2), ("PT_SET", 1, 1), ("NO_CONNECT", 0, 0))),
)

NODE_MAP = RegisterMap(
    name="sbs617",
    size=0x20,
    space=AddressSpace.A32,
    doc="SBS/Bit 3 Model 617 node registers (emulator's declaration, from docs/boards/sbs617.md)",
    registers=tuple(
        Register(name, off, Width.D8, acc, reset=reset,
                 fields=tuple(Field(f, lsb, msb - lsb + 1) for f, msb, lsb in fields))
        for name, off, acc, reset, fields in _NODE_TABLE
    ),
)
MAP_ENTRY_MAP = RegisterMap(
    name="sbs617-map",
    size=0x10000,
    space=AddressSpace.A32,
    doc="the form of a PCI->VME entry (emulator's declaration, from docs/boards/sbs617.md)",
    registers=(Register("PCI_VME_MAP", 0x0000, Width.D32, Access.RW, fields=(
        Field("VME_PAGE", 12, 20), Field("AM", 6, 6), Field("FUNCTION", 4, 2), Field("BYTE_SWAP", 3),
        Field("WORD_SWAP", 2), Field("WBYTE_SWAP", 1), Field("INVALID", 0))),),
)

# LOC_STATUS bits (doc: "Local status and errors")
PARITY, REMBUS, PR_INT, TIMEOUT, LRC, NO_CONNECT = 0x80, 0x40, 0x20, 0x04, 0x02, 0x01
LATCHED = PARITY | REMBUS | TIMEOUT | LRC
# LOC_CMD1 and LOC_INT_CTRL bits
CMD_CLR_ERROR, CMD_CLR_PR, CMD_SND_PT = 0x80, 0x40, 0x20
IC_ACT, IC_EN, IC_ERR_EN, IC_STORED = 0x80, 0x40, 0x20, 0x67
# REM_CMD1 (write) bits
RC_RESET, RC_CLR_PT, RC_SND_PR, RC_LOCK, RC_PG = 0x80, 0x40, 0x20, 0x10, 0x08

PAGE = 0x1000
ENTRIES = 0x10000 // 4  # the whole mapping RAM, D32 entries; the first 8192 are PCI->VME
WINDOW_BYTES = 8192 * PAGE  # 32 MiB
ENTRY_INVALID = 0x00000001
# functions that reach the remote VMEbus: 1 remote bus I/O (vmedrv maps every page so), 2 remote
# bus RAM (NetBSD's); 3, the remote card's dual-port RAM, is not fitted on the emulated remote card
REMOTE_BUS_FUNCTIONS = (1, 2)
# The address size an AM code selects (VMEbus AM table): A24 0x38-0x3F, A32 0x08-0x0F.
_AM_SPACE = {**{am: AddressSpace.A24 for am in range(0x38, 0x40)}, **{am: AddressSpace.A32 for am in range(0x08, 0x10)}}
_REMOTE_REGS = ("REM_CMD1_STATUS", "REM_CMD2", "REM_PAGE_LO", "REM_PAGE_HI", "REM_CARD_ID", "REM_AMOD",
                "REM_IACK", "REM_IACK_BYTE", "RDMA_LEN_CNT", "RDMA_ADDR_A23", "RDMA_ADDR_A31", "RDMA_ADDR_A7",
                "RDMA_ADDR_A15", "REM_SLAVE_STATUS")


class Sbs617Card(RegisterBoard):
    """The 617's node registers; on installation also its mapping RAM and window (A32 BARs).

    Args:
        name: board name; the other BARs are ``"<name>.map"`` and ``"<name>.window"``.
        link: the cable, the remote crate's power, the vision computer's memory (a new
            in-process :class:`Bit3Link` with the remote crate on, by default).
        map_base, window_base: BAR 2 and BAR 3 in the space the card is installed in.
        remote_space, remote_base: where the vision computer's memory is on the remote bus.
        irq_level, irq_vector: how the card's PCI interrupt is delivered on the emulated bus.
        poll_period_s: how often (simulated) the card looks for the remote side's interrupts
            when the remote side is another process (``None``: in-process callback only).
        interface_timeout_s: how long a remote access waits before it times out.
    """

    TYPE = "sbs617"
    REGMAP = NODE_MAP
    irq_release = "rora"
    FAULTS = {  # noqa: RUF012
        "link_down": "cable out: NO_CONNECT; window and remote-register cycles time out (TIMEOUT_ERR)",
        "remote_timeout": "the remote bus does not answer (params: start, end remote offsets): TIMEOUT_ERR",
        "remote_berr": "the remote memory answers BERR (params: start, end remote offsets): REMBUS_ERR",
        "parity": "parity errors on the cable (params: count, default 1): PARITY_ERR",
    }

    def __init__(
        self,
        name: str,
        link: Bit3Link | None = None,
        *,
        map_base: int = 0x80010000,
        window_base: int = 0x82000000,
        remote_space: AddressSpace | str = AddressSpace.A24,
        remote_base: int = 0x400000,
        irq_level: int = 3,
        irq_vector: int = 0xB3,
        poll_period_s: float | None = None,
        interface_timeout_s: float = 32e-6,
    ) -> None:
        if link is None:
            link = Bit3Link(0x1000)
            link.remote_power = True
        self.link = link
        self._bells_seen = link.bells_to_local()[0]
        self._latched = 0
        self._to_local = False  # the programmed interrupt to this card (doc "Open points" 1)
        self._was_reset = True
        self._locked = False
        self._page_mode = False
        self._iack_level = 0
        super().__init__(name)
        for reg in _REMOTE_REGS:  # every remote register crosses the cable first
            self.__dict__[f"read_{reg}"] = partial(self._remote_read, reg)
            if NODE_MAP[reg].access.writable:
                self.__dict__[f"write_{reg}"] = partial(self._remote_write, reg)
        space = AddressSpace.parse(remote_space)
        if space not in (AddressSpace.A24, AddressSpace.A32):
            raise ValueError(f"{name}: the remote memory must be in A24 or A32, not {space.name}")
        if not 1 <= irq_level <= 7 or not 0 <= irq_vector <= 0xFF:
            raise ValueError(f"{name}: IRQ level {irq_level} must be 1..7 and vector {irq_vector} 0..255")
        self.remote_space = space
        self.remote_base = int(remote_base)
        self.irq_level, self.irq_vector = irq_level, irq_vector
        self.map_ram = Sbs617MapRam(f"{name}.map", name)
        self.window = Sbs617Window(f"{name}.window", self)
        self.map_base, self.window_base = int(map_base), int(window_base)
        self.poll_period_ns = None if poll_period_s is None else max(1, round(poll_period_s * 1e9))
        self.interface_timeout_ns = round(interface_timeout_s * 1e9)
        link.add_local_listener(self.poll_doorbell)

    # --- crate hooks ---------------------------------------------------------------------
    def attach(self, crate: Any) -> None:
        super().attach(crate)
        # the BARs are the card's: in its slot (the crate's next free one would name another card's)
        crate.install(self.map_ram, base=self.map_base, space=self.space, slot=self.slot)
        crate.install(self.window, base=self.window_base, space=self.space, slot=self.slot)
        if self.poll_period_ns is not None:
            crate.clock.schedule_in(self.poll_period_ns, self._poll_event)

    def _poll_event(self) -> None:
        self.poll_doorbell()
        if self.crate is not None and self.poll_period_ns is not None:
            self.crate.clock.schedule_in(self.poll_period_ns, self._poll_event)

    @classmethod
    def from_lanes(cls, boards: Sequence[Board], crate: Any) -> Board:
        """Lane 0's card when every lane's card is idle alike: the same node registers and card
        state, mapping RAM, vision-computer memory, remote power and programmed interrupts, no
        polling, nothing injected. Installing it in the lane crate installs its mapping RAM and
        window there too (its BARs: lane 0's, as the card is). A card in use, or one whose state
        differs between lanes, has no lane form (its BARs have none of their own)."""
        def state(b: Board) -> Any:
            if not isinstance(b, Sbs617Card) or b.poll_period_ns is not None:
                return None
            link = b.link
            card = (b._bells_seen, b._latched, b._to_local, b._was_reset, b._locked, b._page_mode, b._iack_level,
                    b.irq_pending)
            return (dict(b.regs), card, tuple(b.map_ram.entries), bytes(link.mem), link.remote_power,
                    link.bells_to_local(), link.bells_to_remote())

        if state(boards[0]) is None:
            raise NotImplementedError(f"board {boards[0].name!r} (sbs617) polls its link: no lane form")
        for b in boards:
            if isinstance(b, Sbs617Card) and (b.map_ram.faulted or b.window.faulted):
                raise NotImplementedError(f"board {b.name!r} (sbs617): a fault injected into its BARs: no lane form")
        return cls._adopt_passive(boards, state)

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "vendor": "SBS Technologies (Bit 3)", "model": "617",
                "document": "docs/boards/sbs617.md", "pci_id": "108A:0001",
                "map": f"{self.space.name} 0x{self.map_base:X}", "window": f"{self.space.name} 0x{self.window_base:X}",
                "remote": f"{self.remote_space.name} 0x{self.remote_base:X} +0x{self.link.mem_size:X}",
                "shm": self.link.shm_name or "-"}

    def reset(self) -> None:
        super().reset()
        if "link" in self.__dict__:
            self._latched = 0
            self._to_local = False
            self._bells_seen = self.link.bells_to_local()[0]

    # --- the link ------------------------------------------------------------------------
    @property
    def link_up(self) -> bool:
        return self.fault("link_down") is None and self.link.remote_power

    def _wait_interface_timeout(self) -> None:
        if self.crate is not None and self.interface_timeout_ns:
            self.crate.clock.advance(self.interface_timeout_ns)

    def _latch(self, bit: int) -> None:
        self._latched |= bit
        self._update_irq()

    def _update_irq(self) -> None:
        ctrl = self.regs["LOC_INT_CTRL"]
        want = bool((ctrl & IC_EN and self._to_local) or (ctrl & IC_ERR_EN and self._latched))
        if want and not self.irq_pending:
            self.request_irq(self.irq_level, self.irq_vector)
        elif not want and self.irq_pending:
            self.release_irq()

    def poll_doorbell(self) -> None:
        """Take the remote side's programmed interrupts rung since the last look."""
        count = self.link.bells_to_local()[0]
        if count == self._bells_seen:
            return
        self._bells_seen = count
        if not self.link_up:
            return  # rung while the cable was out: lost
        self._to_local = True
        self._update_irq()

    # --- local registers -----------------------------------------------------------------
    def read_LOC_CMD1(self) -> int:
        return self.regs["LOC_CMD1"] & CMD_SND_PT  # the one-shot bits read 0

    def write_LOC_CMD1(self, value: int) -> None:
        if value & CMD_CLR_ERROR:
            self._latched = 0
        if value & CMD_CLR_PR:
            self._to_local = False
        if value & CMD_SND_PT:
            self._to_local = True
        self.regs["LOC_CMD1"] = value & CMD_SND_PT
        self._update_irq()

    def read_LOC_INT_CTRL(self) -> int:
        return (self.regs["LOC_INT_CTRL"] & IC_STORED) | (IC_ACT if self.irq_pending else 0)

    def write_LOC_INT_CTRL(self, value: int) -> None:
        self.regs["LOC_INT_CTRL"] = value & IC_STORED
        self._update_irq()

    def read_LOC_STATUS(self) -> int:
        return self._latched | (PR_INT if self._to_local else 0) | (0 if self.link_up else NO_CONNECT)

    # --- remote registers (across the cable) ---------------------------------------------
    def _remote_read(self, reg: str) -> int:
        if not self.link_up:
            self._wait_interface_timeout()
            self._latch(TIMEOUT)
            return 0xFF
        if reg == "REM_CMD1_STATUS":
            level = self._iack_level
            value = ((0x80 if self._was_reset else 0) | (0x40 if level & 2 else 0) | (0x04 if level & 4 else 0)
                     | (level & 1) | (0 if self._locked else 0x10) | (0x08 if self._page_mode else 0)
                     | (0x02 if self._to_local else 0))
            self._was_reset = False  # the reset sequence's discarded read (doc, Open points 5)
            return value
        if reg in ("REM_IACK", "REM_IACK_BYTE"):  # no interrupters on the emulated remote bus
            self._latch(REMBUS)
            return 0xFF
        if reg == "REM_SLAVE_STATUS":
            return 0x02 if self._to_local else 0x00
        return self.regs[reg]

    def _remote_write(self, reg: str, value: int) -> None:
        if not self.link_up:
            self._wait_interface_timeout()
            self._latch(TIMEOUT)
            return
        if reg != "REM_CMD1_STATUS":
            self.regs[reg] = value
            return
        if value & RC_RESET:
            self._was_reset = True
        if value & RC_CLR_PT:
            self._to_local = False
            self._update_irq()
        self._locked = bool(value & RC_LOCK)
        self._page_mode = bool(value & RC_PG)
        self._iack_level = value & 0x07
        if value & RC_SND_PR:
            self.link.ring_remote(0)  # a single bit: the code is not carried

    # --- the window ----------------------------------------------------------------------
    def window_cycle(self, offset: int, width: Width, value: int | None) -> int:
        """One host cycle in the window, decided in the doc's order ("Window cycles")."""
        n = int(width)
        fail = (1 << (8 * n)) - 1
        entry = self.map_ram.entries[offset // PAGE]
        if entry & ENTRY_INVALID:
            self._latch(REMBUS)
            return fail
        if not self.link_up:
            self._wait_interface_timeout()
            self._latch(TIMEOUT)
            return fail
        address = (entry & 0xFFFFF000) | (offset % PAGE)
        rel = address - self.remote_base
        if self.faulted:
            parity = self.fault("parity")
            if parity is not None:
                left = int(parity.get("count", 1)) - 1
                if left > 0:
                    parity["count"] = left
                else:
                    self.clear_fault("parity")
                self._latch(PARITY)
                return fail
            quiet = self.fault("remote_timeout")
            if quiet is not None and quiet.get("start", 0) <= rel < quiet.get("end", 1 << 32):
                self._wait_interface_timeout()
                self._latch(TIMEOUT)
                return fail
        function = (entry >> 4) & 0x3
        am = (entry >> 6) & 0x3F
        if (function not in REMOTE_BUS_FUNCTIONS or _AM_SPACE.get(am) is not self.remote_space
                or not 0 <= rel <= self.link.mem_size - n):
            self._latch(REMBUS)  # nothing answers on the remote bus: its bus timer ends it in BERR
            return fail
        if self.faulted:
            berr = self.fault("remote_berr")
            if berr is not None and berr.get("start", 0) <= rel < berr.get("end", 1 << 32):
                self._latch(REMBUS)
                return fail
        mem = self.link.mem
        if value is None:
            return int.from_bytes(mem[rel:rel + n], "big")
        mem[rel:rel + n] = value.to_bytes(n, "big")
        return 0


class Sbs617MapRam(Board):
    """BAR 2: 64 KiB of D32 mapping entries (every one invalid at power-up)."""

    TYPE = "sbs617-map"

    def __init__(self, name: str, card: str) -> None:
        super().__init__(name, 4 * ENTRIES)
        self.card = card
        self.entries = [ENTRY_INVALID] * ENTRIES

    def reset(self) -> None:
        super().reset()
        if "entries" in self.__dict__:
            self.entries = [ENTRY_INVALID] * ENTRIES

    def _index(self, offset: int, width: Width) -> int:
        if width is not Width.D32:
            raise BoardAccessError(BusErrorCause.UNSUPPORTED_WIDTH, f"{self.name}: mapping RAM is D32 only")
        return offset // 4

    def bus_read(self, offset: int, width: Width) -> int:
        return self.entries[self._index(offset, width)]

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        self.entries[self._index(offset, width)] = value & 0xFFFFFFFF

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "card": self.card, "size": self.size}


class Sbs617Window(Board):
    """BAR 3: the 32 MiB window; every cycle goes to :meth:`Sbs617Card.window_cycle`."""

    TYPE = "sbs617-window"
    access_ns = 1000  # a remote cycle crosses the cable and the remote bus (doc "Timing": a choice)

    def __init__(self, name: str, card: Sbs617Card) -> None:
        super().__init__(name, WINDOW_BYTES)
        self.card = card

    def bus_read(self, offset: int, width: Width) -> int:
        return self.card.window_cycle(offset, width, None)

    def bus_write(self, offset: int, width: Width, value: int) -> None:
        self.card.window_cycle(offset, width, value)

    def describe(self) -> dict[str, Any]:
        return {"type": self.TYPE, "card": self.card.name, "size": self.size}


def sbs617_factory(name: str, cfg: ConfigTable, ctx: BuildContext) -> Sbs617Card:
    """Crate-file factory for ``type = "sbs617"`` (docs/boards/sbs617.md, "Crate file")."""
    map_base = cfg.get_int("map_base", min=0, max=(1 << 32) - 1)
    window_base = cfg.get_int("window_base", min=0, max=(1 << 32) - 1)
    remote_space = cfg.get_str("remote_space", "A24", choices=("A24", "A32"))
    remote_base = cfg.get_int("remote_base", min=0, max=(1 << 32) - 1)
    irq_level = cfg.get_int("irq_level", 3, min=1, max=7)
    irq_vector = cfg.get_int("irq_vector", 0xB3, min=0, max=0xFF)
    mem_size = cfg.get_int("mem_size", 0x1000, min=4, max=1 << 25)
    shm = cfg.get_str("shm", "")
    if shm:  # the creator of the segment sets its size
        link = Bit3Link.attach_shared(shm)
        poll_us = cfg.get_float("poll_period_us", 50.0, min=1.0, max=1e6)
    else:
        link = Bit3Link(mem_size)
        link.remote_power = True
        poll_us = cfg.get_float("poll_period_us", 0.0, min=0.0, max=1e6)
    return Sbs617Card(name, link, map_base=map_base, window_base=window_base, remote_space=remote_space,
                      remote_base=remote_base, irq_level=irq_level, irq_vector=irq_vector,
                      poll_period_s=poll_us * 1e-6 if poll_us else None)
