"""Register map of the VMIC VMIVME-3113A scanning 12-bit ADC, 64 channels (A16 short I/O, D16).

The driver's reading of ``docs/boards/vmivme-3113a.md`` (the spec, citing DFELL_EPICS
``vmi3113A/drvVmi3113A.h``); the emulator ``emulators.vmivme3113a`` has its own, and tests check
each against the doc's table.

CSR (+0x02)::

    15                14            13                  12     11        10           9      8..6
    NEW_DATA_READY    FAIL_LED_OFF  END_OF_SCAN         TWOS   EN_EXT    TIMER_START  RESET  MODE
    (write: GAIN_DELAY)             (write: START_CONVERT)

Data words CH0..CH63 at 0x80 + 2·k: the 12-bit code in bits 11:0; bits 15:12 zero (offset
binary) or the sign (two's complement).
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

VMI3113A_BOARD_ID = 0x1100  #: the ID register (the source's `bid`)
VMI3113A_CHANNELS = 64
VMI3113A_DATA_OFFSET = 0x80  #: CH0; CHk at 0x80 + 2·k
VMI3113A_WINDOW = 0x100

#: CSR.MODE values
MODE_AUTOSCANNING = 0
MODE_RANDOM_POLL = 1
MODE_RANDOM_INTERRUPT = 2
MODE_SCANNING_POLL = 3
MODE_SCANNING_INTERRUPT = 4

_CSR_FIELDS = (
    Field("MODE", 6, 3, "0 autoscanning, 1 random poll, 2 random interrupt, 3 scanning poll, 4 scanning interrupt"),
    Field("SOFTWARE_RESET", 9, 1, "write 1: reset the board (reads 0)"),
    Field("TIMER_START", 10, 1, "start conversions from the on-board timer"),
    Field("EN_EXTERNAL_START", 11, 1, "external start enable"),
    Field("TWOS_COMPLEMENT", 12, 1, "1: two's complement data; 0: offset binary"),
    Field("END_OF_SCAN", 13, 1, "read: a 64-channel scan ended since the last CSR read; write 1: START_CONVERT"),
    Field("FAIL_LED_OFF", 14, 1, "1: front-panel FAIL LED off"),
    Field("NEW_DATA_READY", 15, 1, "read: a conversion ended since the last CSR read; write: GAIN_DELAY"),
)

_DATA_FIELDS = (
    Field("CODE", 0, 12, "the channel's latest 12-bit code"),
    Field("EXT", 12, 4, "0 (offset binary) or copies of bit 11 (two's complement)"),
)

VMI3113A_REGMAP = RegisterMap(
    "vmivme3113a",
    VMI3113A_WINDOW,
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO, reset=VMI3113A_BOARD_ID, doc="board ID, 0x1100"),
        Register("CSR", 0x02, Width.D16, Access.RW, _CSR_FIELDS, doc="control and status"),
        Register("CFR", 0x04, Width.D16, Access.RW, doc="configuration control (bits not public)"),
        Register("ICR", 0x0A, Width.D16, Access.RW,
                 (Field("LEVEL", 0, 3, "request level 1..7; 0: off"),
                  Field("INTR_AUTO_CLEAR", 3, 1, "IACK clears INTERRUPT_ENABLE"),
                  Field("INTERRUPT_ENABLE", 4, 1, "the board may request its interrupt"),
                  Field("EXTERNAL_VECTOR", 5, 1, "vector source"),
                  Field("FLAG_AUTO_CLEAR", 6, 1, "IACK clears FLAG"),
                  Field("FLAG", 7, 1, "general flag")),
                 doc="interrupt control"),
        Register("IVR", 0x12, Width.D16, Access.RW, (Field("VECTOR", 0, 8, "status/ID on IACK"),), reset=0x0F,
                 doc="interrupt vector"),
        Register("TM0", 0x20, Width.D16, Access.RW, doc="timer 0"),
        Register("TM1", 0x22, Width.D16, Access.RW, doc="timer 1"),
        Register("TM2", 0x24, Width.D16, Access.RW, doc="timer 2"),
        Register("TMC", 0x26, Width.D16, Access.WO,
                 (Field("BCD", 0, 1, "BCD counter"), Field("MODE", 1, 3, "counter mode"),
                  Field("RW", 4, 2, "latch / LSB / MSB / LSB then MSB"),
                  Field("SELECT", 6, 2, "counter 0..2; 3: read-back")),
                 doc="timer control word"),
        *(
            Register(f"CH{k}", VMI3113A_DATA_OFFSET + 2 * k, Width.D16, Access.RO, _DATA_FIELDS,
                     doc=f"data of channel {k}")
            for k in range(VMI3113A_CHANNELS)
        ),
    ),
    doc="VMIC VMIVME-3113A scanning 12-bit ADC, 64 channels",
)
