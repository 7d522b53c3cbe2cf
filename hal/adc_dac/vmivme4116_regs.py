"""Register map of the VMIC VMIVME-4116 (8 channels, 16 bit analog output; A16 short I/O, D16).

The driver's reading of ``docs/boards/vmivme4116.md`` (the spec, which cites the public sources:
Duke FEL's ``drvVmi4116.h``/``.c``, EPICS base's VMI 4100-family support, VMIC's product sheet);
the emulator ``emulators.vmivme4116`` has its own, and tests check each against the doc's table.

Eight write-only channel data latches at +0x00..+0x0E, the CSR at +0x10; no ID register. Codes
are 16 bit over −10 V … +10 V, offset binary (0x8000 = 0 V) or two's complement (a board setting).
"""

from __future__ import annotations

from hal.vme.registers import Access, Field, Register, RegisterMap
from hal.vme.types import AddressSpace, Width

VMI4116_CHANNELS = 8
VMI4116_WINDOW = 0x20  #: one 32-byte block per board (``chan[8]; csr; unused[7]``)
VMI4116_CHAN_OFFSET = 0x00  #: CHAN0; CHANn at 2·n
VMI4116_CSR_OFFSET = 0x10

_CODE = (Field("CODE", 0, 16, "the channel's 16-bit code (offset binary or two's complement)"),)

VMI4116_REGMAP = RegisterMap(
    "vmivme-4116",
    VMI4116_WINDOW,
    AddressSpace.A16,
    (
        *(
            Register(f"CHAN{i}", VMI4116_CHAN_OFFSET + 2 * i, Width.D16, Access.WO, _CODE, reset=0x8000,
                     doc=f"data latch of channel {i} (write-only: reads do not return it)")
            for i in range(VMI4116_CHANNELS)
        ),
        Register("CSR", VMI4116_CSR_OFFSET, Width.D16, Access.RW,
                 (Field("AO_P3", 8, 1, "1: outputs connected to the P3 connector"),
                  Field("START_CONVERT", 9, 1, "write 1: update all outputs (synchronized update mode); reads 0"),
                  Field("TESTBUS", 11, 1, "1: analog output to the test bus"),
                  Field("AINTESTBS", 12, 1, "1: enable test bus 1"),
                  Field("AOTESTBS", 13, 1, "1: enable test bus 2"),
                  Field("LED_OFF", 14, 1, "1: front-panel fail LED off")),
                 reset=0x0000, doc="control and status"),
    ),
    doc="VMIC VMIVME-4116: 8-channel 16-bit ±10 V analog output",
)
