"""The Linux ``vme_user`` user-space ABI: ``struct vme_master``, ``struct vme_irq_id``, the ioctl
request numbers and the ``vme.h`` attribute bits, for both layouts the kernel has shipped.

Sources (read, not guessed; see ``tests/hal/vme_user/vme_user_abi.h`` for the vendored copy):

* ``drivers/staging/vme/devices/vme_user.h`` up to v3.10 (e.g. the 3.10 Android trees): the
  *unpacked* layout — ``int enable; unsigned long long vme_addr, size; u32 aspace, cycle,
  dwidth;`` with natural alignment: 40 bytes on x86-64/arm64/ppc64 (4 bytes of padding after
  ``enable``), 32 bytes on i386 (where a 64-bit member is 4-aligned).
* the same file in v3.18 … v4.x, then ``drivers/staging/vme_user/vme_user.h`` (v5.x … v6.x):
  the *packed* layout — ``__u32 enable; __u64 vme_addr, size; __u32 aspace, cycle, dwidth;``
  with ``__packed``: 32 bytes everywhere. ``VME_IRQ_GEN`` (``struct vme_irq_id { __u8 level;
  __u8 statid; }``) is present in both.
* ``VME_A16`` … ``VME_D64`` from ``vme.h`` (``include/linux/vme.h``, later
  ``drivers/staging/vme_user/vme.h``), unchanged across those versions.

The request numbers encode the struct size (``_IOR(0xAE, 3, struct vme_master)``), so the two
layouts have different numbers: a kernel answers ``EINVAL`` (its ``default:`` case) to the
other layout's number, which is how :func:`hal.vme.vme_user.VmeUserBus` probes. Where the two
layouts are byte-identical (i386) the numbers coincide too and either is right.
"""

from __future__ import annotations

import ctypes
import enum
import platform
import re

VME_IOC_MAGIC = 0xAE

# --- vme.h ---------------------------------------------------------------------------------
VME_A16 = 0x1
VME_A24 = 0x2
VME_A32 = 0x4
VME_A64 = 0x8
VME_CRCSR = 0x10

VME_SCT = 0x1
VME_BLT = 0x2
VME_MBLT = 0x4
VME_2eVME = 0x8
VME_2eSST = 0x10
VME_2eSSTB = 0x20
VME_SUPER = 0x1000
VME_USER = 0x2000
VME_PROG = 0x4000
VME_DATA = 0x8000

VME_D8 = 0x1
VME_D16 = 0x2
VME_D32 = 0x4
VME_D64 = 0x8

MASTER_WINDOWS = 4  #: vme_user exposes m0..m3 (minors 0..3), whatever the bridge has
CONTROL_DEVICE = "ctl"  #: minor 8: VME_IRQ_GEN


class VmeMasterUnpacked(ctypes.Structure):
    """``struct vme_master`` before ``__packed`` (kernels up to 3.10): natural alignment."""

    _fields_ = [
        ("enable", ctypes.c_int),
        ("vme_addr", ctypes.c_ulonglong),
        ("size", ctypes.c_ulonglong),
        ("aspace", ctypes.c_uint32),
        ("cycle", ctypes.c_uint32),
        ("dwidth", ctypes.c_uint32),
    ]


class VmeMasterPacked(ctypes.Structure):
    """``struct vme_master { __u32 ...; __u64 ...; } __packed`` (3.18 and later): 32 bytes."""

    _pack_ = 1
    _fields_ = [
        ("enable", ctypes.c_uint32),
        ("vme_addr", ctypes.c_uint64),
        ("size", ctypes.c_uint64),
        ("aspace", ctypes.c_uint32),
        ("cycle", ctypes.c_uint32),
        ("dwidth", ctypes.c_uint32),
    ]


class VmeIrqId(ctypes.Structure):
    """``struct vme_irq_id { __u8 level; __u8 statid; }`` (the control device's VME_IRQ_GEN)."""

    _fields_ = [("level", ctypes.c_uint8), ("statid", ctypes.c_uint8)]


VmeMasterStruct = VmeMasterUnpacked | VmeMasterPacked


class Layout(enum.Enum):
    """Which ``struct vme_master`` the running kernel was built with."""

    UNPACKED = "unpacked"
    PACKED = "packed"

    @property
    def struct(self) -> type[VmeMasterUnpacked] | type[VmeMasterPacked]:
        return VmeMasterUnpacked if self is Layout.UNPACKED else VmeMasterPacked


# --- asm-generic/ioctl.h, and the variant of powerpc, mips and sparc -------------------------
_IOC_NRBITS = 8
_IOC_TYPEBITS = 8


def _ioc_params(machine: str) -> tuple[int, int, int, int]:
    """(size bits, NONE, WRITE, READ) of ``_IOC`` on a CPU as ``uname -m`` names it."""
    m = machine.lower()
    if m.startswith(("ppc", "powerpc", "mips", "sparc")):
        return 13, 1, 4, 2
    return 14, 0, 1, 2


def ioc(direction: str, nr: int, size: int, *, magic: int = VME_IOC_MAGIC, machine: str | None = None) -> int:
    """``_IOC(dir, magic, nr, size)``; ``direction`` is ``"r"`` (``_IOR``), ``"w"`` (``_IOW``) or ``""``."""
    size_bits, none, write, read = _ioc_params(machine or platform.machine())
    if not 0 <= size < (1 << size_bits):
        raise ValueError(f"ioctl argument size {size} does not fit {size_bits} bits")
    d = {"": none, "w": write, "r": read, "rw": read | write}[direction]
    nr_shift = 0
    type_shift = nr_shift + _IOC_NRBITS
    size_shift = type_shift + _IOC_TYPEBITS
    dir_shift = size_shift + size_bits
    return (d << dir_shift) | (size << size_shift) | (magic << type_shift) | (nr << nr_shift)


def vme_get_master(layout: Layout, machine: str | None = None) -> int:
    """``VME_GET_MASTER = _IOR(VME_IOC_MAGIC, 3, struct vme_master)`` for ``layout``."""
    return ioc("r", 3, ctypes.sizeof(layout.struct), machine=machine)


def vme_set_master(layout: Layout, machine: str | None = None) -> int:
    """``VME_SET_MASTER = _IOW(VME_IOC_MAGIC, 4, struct vme_master)`` for ``layout``."""
    return ioc("w", 4, ctypes.sizeof(layout.struct), machine=machine)


def vme_irq_gen(machine: str | None = None) -> int:
    """``VME_IRQ_GEN = _IOW(VME_IOC_MAGIC, 5, struct vme_irq_id)``."""
    return ioc("w", 5, ctypes.sizeof(VmeIrqId), machine=machine)


PACKED_SINCE = (3, 18)
"""The first release checked to have the packed layout. v3.10 is the last checked to have the
unpacked one: for 3.11 … 3.17 the version alone does not decide, so the backend probes."""


def layout_for_kernel(release: str) -> Layout | None:
    """The layout a kernel release (``uname -r``) is known to have, or ``None`` if unknown."""
    m = re.match(r"(\d+)\.(\d+)", release)
    if not m:
        return None
    version = (int(m.group(1)), int(m.group(2)))
    if version >= PACKED_SINCE:
        return Layout.PACKED
    if version <= (3, 10):
        return Layout.UNPACKED
    return None


# --- attribute words <-> the bus's own types --------------------------------------------------
def aspace_bits(space_bits: int) -> int:
    """``VME_A16``/``VME_A24``/``VME_A32`` for an address space of 16/24/32 bits."""
    try:
        return {16: VME_A16, 24: VME_A24, 32: VME_A32}[space_bits]
    except KeyError:
        raise ValueError(f"no vme_user address space for A{space_bits}") from None


def dwidth_bits(width_bytes: int) -> int:
    """``VME_D8``/``VME_D16``/``VME_D32`` for 1/2/4 bytes."""
    try:
        return {1: VME_D8, 2: VME_D16, 4: VME_D32}[width_bytes]
    except KeyError:
        raise ValueError(f"no vme_user data width for {width_bytes} bytes") from None


def cycle_bits(*, supervisory: bool, program: bool, block: bool) -> int:
    """The ``cycle`` word: transfer mode (SCT or BLT), privilege and program/data."""
    return (
        (VME_BLT if block else VME_SCT)
        | (VME_SUPER if supervisory else VME_USER)
        | (VME_PROG if program else VME_DATA)
    )
