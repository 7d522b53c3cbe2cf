"""Register map of the 8-channel 12-bit double-buffered DAC board (A16 short I/O, D16, big-endian).

The driver's reading of ``docs/boards/dac.md`` (the spec); the emulator ``emulators.dac.DacBoard``
has its own, and tests check each against the doc's table.

Each channel has a holding register (``DATAn``, written by the host) and an output register
(``OUTn``, driving the converter). Writing ``DATAn`` changes nothing at the output; an update
strobe — ``UPDATE`` bit *n*, or ``CSR.UPDATE_ALL`` — copies holding → output for the selected
channels in the same instant. Codes are ±10 V offset binary (0x800 = 0 V, the power-up value).
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

DAC_BOARD_ID = 0xDA08  #: value of the ID register ("DAC, 8 channels")
DAC_CHANNELS = 8
DAC_DATA_OFFSET = 0x10  #: DATA0; DATAn at 0x10 + 2·n
DAC_OUT_OFFSET = 0x20  #: OUT0; OUTn at 0x20 + 2·n
DAC_WINDOW = 0x30
DAC_POWER_UP_CODE = 0x800  #: 0 V

_CODE = (Field("CODE", 0, 12, "offset-binary code (bits 15:12 ignored on write, read 0)"),)

DAC_REGMAP = RegisterMap(
    "dac8",
    DAC_WINDOW,
    AddressSpace.A16,
    (
        Register("ID", 0x00, Width.D16, Access.RO, reset=DAC_BOARD_ID, also=(Width.D8,),
                 doc=f"board ID, always 0x{DAC_BOARD_ID:04X}"),
        Register("CSR", 0x02, Width.D16, Access.RW,
                 (Field("UPDATE_ALL", 0, 1, "write 1: copy every holding register to its output (reads 0)"),
                  Field("SETTLING", 1, 1, "RO: an output is still settling after an update"),
                  Field("RESET", 15, 1, "write 1: reset — all holding and outputs to 0x800 (0 V); reads 0")),
                 also=(Width.D8,), doc="control/status"),
        Register("UPDATE", 0x04, Width.D16, Access.WO,
                 tuple(Field(f"CH{i}", i, 1, f"1: copy DATA{i} to OUT{i}") for i in range(DAC_CHANNELS)),
                 also=(Width.D8,),
                 doc="per-channel update strobe; all channels written as 1 update simultaneously"),
        *(
            Register(f"DATA{i}", DAC_DATA_OFFSET + 2 * i, Width.D16, Access.RW, _CODE, reset=DAC_POWER_UP_CODE,
                     doc=f"holding register of channel {i} (no effect on the output until a strobe)")
            for i in range(DAC_CHANNELS)
        ),
        *(
            Register(f"OUT{i}", DAC_OUT_OFFSET + 2 * i, Width.D16, Access.RO, _CODE, reset=DAC_POWER_UP_CODE,
                     doc=f"readback of the code driving output {i}")
            for i in range(DAC_CHANNELS)
        ),
    ),
    doc="8-channel 12-bit ±10 V double-buffered DAC",
)
