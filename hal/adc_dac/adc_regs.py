"""Register map of the 16-channel 12-bit ADC board (A16 short I/O, D16, big-endian).

The driver's reading of ``docs/boards/adc.md`` (the spec: table, timing, behaviour); the emulator
``emulators.adc.AdcBoard`` has its own, and tests check each against the doc's table.

CSR layout (D16 at +0x02; D8 allowed — the *high* byte +0x02 holds configuration, the *low*
byte +0x03 holds the action and status bits, so a D8 write of ``START`` to +0x03 starts a
conversion without touching the configuration)::

    15     14..13  12     11..9      8       7         6   5        4      3     2     1     0
    RESET  -       RANGE  IRQ_LEVEL  IRQ_EN  IRQ_PEND  -   OVERRUN  EARLY  DONE  BUSY  SCAN  START

Data word format (DATA and BUF0..BUF15)::

    15..12   11..0
    CHANNEL  CODE     (CODE: offset binary in the bipolar range, straight binary in unipolar)
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

ADC_BOARD_ID = 0xAD16  #: value of the ID register ("ADC, 16 channels")
ADC_CHANNELS = 16
ADC_BUFFER_OFFSET = 0x20  #: BUF0; BUFn is at 0x20 + 2·n
ADC_WINDOW = 0x40

_CSR_FIELDS = (
    Field("START", 0, 1, "write 1: start one conversion of CHAN (reads 0)"),
    Field("SCAN", 1, 1, "write 1: start a scan of channels 0..SCAN_LAST into BUF (reads 0)"),
    Field("BUSY", 2, 1, "RO: a conversion or scan is in progress"),
    Field("DONE", 3, 1, "RO: the last conversion/scan finished (cleared by the next start)"),
    Field("EARLY", 4, 1, "W1C: DATA or BUF was read while busy (stale value returned)"),
    Field("OVERRUN", 5, 1, "W1C: start or scan requested while busy (request ignored)"),
    Field("IRQ_PEND", 7, 1, "W1C: end-of-conversion interrupt requested (RORA: write 1 to release)"),
    Field("IRQ_EN", 8, 1, "1: interrupt at the end of each conversion/scan"),
    Field("IRQ_LEVEL", 9, 3, "IRQ1..7 (0: no interrupt even if IRQ_EN)"),
    Field("RANGE", 12, 1, "0: ±10 V/gain offset binary; 1: 0..10 V/gain straight binary"),
    Field("RESET", 15, 1, "write 1: software reset to power-up state (reads 0)"),
)

#: CSR bits that clear when written with 1 (a driver must write 0 there to leave them alone).
CSR_W1C_MASK = (1 << 4) | (1 << 5) | (1 << 7)
#: CSR bits that are plain read/write configuration.
CSR_CONFIG_MASK = (1 << 8) | (0x7 << 9) | (1 << 12)

_DATA_FIELDS = (
    Field("CODE", 0, 12, "12-bit conversion result"),
    Field("CHANNEL", 12, 4, "channel that produced CODE"),
)


def _gain_fields(first: int) -> tuple[Field, ...]:
    return tuple(
        Field(f"CH{first + i}", 2 * i, 2, "gain code 0..3 = ×1, ×2, ×4, ×8") for i in range(8)
    )


ADC_REGMAP = RegisterMap(
    "adc16",
    ADC_WINDOW,
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO, reset=ADC_BOARD_ID, also=(Width.D8,),
                 doc=f"board ID, always 0x{ADC_BOARD_ID:04X}"),
        Register("CSR", 0x02, Width.D16, Access.RW, _CSR_FIELDS, also=(Width.D8,),
                 doc="control/status (bits above; W1C flags, START/SCAN/RESET are strobes)"),
        Register("CHAN", 0x04, Width.D16, Access.RW,
                 (Field("CHANNEL", 0, 4, "channel 0..15 for START"),
                  Field("GAIN", 4, 2, "gain code 0..3 = ×1, ×2, ×4, ×8")),
                 doc="channel and gain of a single conversion"),
        Register("DATA", 0x06, Width.D16, Access.RO, _DATA_FIELDS,
                 doc="last single-conversion result; read while BUSY returns the stale word and sets EARLY"),
        Register("VECTOR", 0x08, Width.D16, Access.RW, (Field("VECTOR", 0, 8, "status/ID on IACK"),),
                 reset=0x0F, doc="interrupt vector (8-bit status/ID; reset 0x0F, uninitialized vector)"),
        Register("SCAN_LAST", 0x0A, Width.D16, Access.RW, (Field("LAST", 0, 4, "last channel"),),
                 reset=ADC_CHANNELS - 1, doc="a scan converts channels 0..LAST in order"),
        Register("SCAN_GAIN0", 0x0C, Width.D16, Access.RW, _gain_fields(0),
                 doc="scan gain codes of channels 0..7 (2 bits each)"),
        Register("SCAN_GAIN1", 0x0E, Width.D16, Access.RW, _gain_fields(8),
                 doc="scan gain codes of channels 8..15 (2 bits each)"),
        *(
            Register(f"BUF{i}", ADC_BUFFER_OFFSET + 2 * i, Width.D16, Access.RO, _DATA_FIELDS,
                     doc=f"scan result of channel {i} (same format as DATA; block-readable)")
            for i in range(ADC_CHANNELS)
        ),
    ),
    doc="16-channel 12-bit ADC with programmable gain and scan sequencer",
)
