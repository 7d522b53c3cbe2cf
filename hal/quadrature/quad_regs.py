"""Register map of the 4-channel quadrature decoder board, the driver's reading of its spec
(docs/boards/quadrature.md; the emulator keeps its own).

Inspired by the LSI LS7166 24-bit quadrature counter (x1/x2/x4, output latch loaded by a
transfer command, preset register, carry/borrow flags) and the HP HCTL-2016/2020 (sampled
digital filter on A/B, latch-then-read so a multi-byte read cannot tear), as mounted four to a
VME card. A16 short I/O, 0xA0 bytes, big-endian, D16 registers that also answer D8.

Global: ``ID`` (RO) at 0x00, ``GCMD`` (WO) at 0x02 — bits [3:0] latch channels 0..3 at the
same instant (one write before reading all axes of an arm).

Channel n at ``0x20 * (n + 1)`` (registers ``CHn_<NAME>``):

====  ======  ======  =========================================================
off   name    access  contents
====  ======  ======  =========================================================
+00   CTL     RW      [1:0] mode 0 = x1, 1 = x2, 2 = x4, 3 = hold; [4] index arm
+02   CMD     WO      [0] latch counter → OL, [1] clear counter, [2] load PRE
+04   STATUS  RW1C    [0] index, [1] illegal, [2] overflow, [3] underflow
                      (W1C); [9:8] A/B levels now (RO)
+08   OL_HI   RO      output latch bits 23:16 in [7:0]
+0A   OL_LO   RO      output latch bits 15:0
+0C   CNT_HI  RO      live counter bits 23:16 (no latch: can tear)
+0E   CNT_LO  RO      live counter bits 15:0
+10   IDX_HI  RO      index latch bits 23:16
+12   IDX_LO  RO      index latch bits 15:0
+14   PRE_HI  RW      preset bits 23:16
+16   PRE_LO  RW      preset bits 15:0
====  ======  ======  =========================================================

A 24-bit value is read as D16 ``*_HI`` + D16 ``*_LO`` or as three D8 bytes at +09, +0A, +0B.
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

BOARD_TYPE = 0x51  #: ID[15:8] of this board type ("Q")
REVISION = 0x01
CHANNELS = 4
CHANNEL_STRIDE = 0x20
COUNTER_BITS = 24
COUNTER_MODULUS = 1 << COUNTER_BITS
COUNTER_MASK = COUNTER_MODULUS - 1

MODE_CODES = {1: 0, 2: 1, 4: 2}  #: counts per quadrature cycle → CTL.mode code
MODE_HOLD = 3  #: CTL.mode code: counting inhibited

CMD_LATCH = 1 << 0
CMD_CLEAR = 1 << 1
CMD_PRESET = 1 << 2

ST_INDEX = 1 << 0
ST_ILLEGAL = 1 << 1
ST_OVERFLOW = 1 << 2
ST_UNDERFLOW = 1 << 3
ST_W1C_MASK = 0xF


def ch_base(ch: int) -> int:
    """Offset of channel ``ch``'s register block."""
    return CHANNEL_STRIDE * (ch + 1)


def reg_name(ch: int, name: str) -> str:
    """``reg_name(2, "OL_HI")`` → ``"CH2_OL_HI"``."""
    return f"CH{ch}_{name}"


def _hi(name: str, off: int, access: Access, doc: str) -> Register:
    return Register(name, off, Width.D16, access, fields=(Field("value", 0, 8, "bits 23:16"),),
                    doc=doc, also=(Width.D8,))


def _lo(name: str, off: int, access: Access, doc: str) -> Register:
    return Register(name, off, Width.D16, access, doc=doc, also=(Width.D8,))


def _channel(ch: int) -> list[Register]:
    b = ch_base(ch)
    n = lambda s: reg_name(ch, s)  # noqa: E731
    return [
        Register(
            n("CTL"), b + 0x00, Width.D16, Access.RW,
            fields=(Field("index_arm", 4, 1, "capture the next index pulse (self-clearing)"),
                    Field("mode", 0, 2, "0 = x1, 1 = x2, 2 = x4, 3 = hold")),
            reset=MODE_CODES[4], doc=f"channel {ch} control", also=(Width.D8,),
        ),
        Register(
            n("CMD"), b + 0x02, Width.D16, Access.WO,
            fields=(Field("preset", 2, 1, "counter := PRE"), Field("clear", 1, 1, "counter := 0"),
                    Field("latch", 0, 1, "OL := counter")),
            doc=f"channel {ch} commands", also=(Width.D8,),
        ),
        Register(
            n("STATUS"), b + 0x04, Width.D16, Access.W1C,
            fields=(Field("b", 9, 1, "B input now (RO)"), Field("a", 8, 1, "A input now (RO)"),
                    Field("underflow", 3, 1, "borrow 0 → 0xFFFFFF"), Field("overflow", 2, 1, "carry 0xFFFFFF → 0"),
                    Field("illegal", 1, 1, "A and B changed in one sample"),
                    Field("index", 0, 1, "armed index captured into IDX")),
            doc=f"channel {ch} status, write 1 to clear [3:0]", also=(Width.D8,),
        ),
        _hi(n("OL_HI"), b + 0x08, Access.RO, "output latch [23:16]"),
        _lo(n("OL_LO"), b + 0x0A, Access.RO, "output latch [15:0]"),
        _hi(n("CNT_HI"), b + 0x0C, Access.RO, "live counter [23:16] (unlatched)"),
        _lo(n("CNT_LO"), b + 0x0E, Access.RO, "live counter [15:0] (unlatched)"),
        _hi(n("IDX_HI"), b + 0x10, Access.RO, "index latch [23:16]"),
        _lo(n("IDX_LO"), b + 0x12, Access.RO, "index latch [15:0]"),
        _hi(n("PRE_HI"), b + 0x14, Access.RW, "preset [23:16]"),
        _lo(n("PRE_LO"), b + 0x16, Access.RW, "preset [15:0]"),
    ]


QUAD_REGS = RegisterMap(
    "quad",
    ch_base(CHANNELS),
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO,
                 fields=(Field("type", 8, 8, "board type 0x51"), Field("rev", 0, 8, "revision")),
                 reset=(BOARD_TYPE << 8) | REVISION, doc="board identification (read-only)", also=(Width.D8,)),
        Register("GCMD", 0x02, Width.D16, Access.WO,
                 fields=(Field("latch", 0, 4, "latch channels (bit n = channel n) simultaneously"),),
                 doc="global command", also=(Width.D8,)),
        *(r for ch in range(CHANNELS) for r in _channel(ch)),
    ),
    doc="four 24-bit quadrature counters with output latch, index latch and preset",
)
