"""A user-space stand-in for ``/dev/bus/vme``: a FUSE file system whose ``m0``..``m3`` answer
``VME_SET_MASTER``/``VME_GET_MASTER`` and forward reads and writes to an emulated crate.

It does what ``drivers/staging/vme_user/vme_user.c`` and the tsi148 bridge driver do, as far as
user space can see: the ioctl numbers of one ``struct vme_master`` layout (``EINVAL`` to any
other request, like the driver's ``default:``), a window refused with ``EINVAL`` when its space,
width or 64 KiB alignment is not the bridge's, reads and writes clamped to the window (an
offset at or past its end reads 0 bytes), transfers split into aligned D8/D16/D32 cycles, a bus
error returned as ``EIO`` (the tsi148 with ``err_chk=1``) and ``VME_IRQ_GEN`` on ``ctl``. Files
are opened with ``direct_io`` so the kernel neither caches nor reads ahead (reads have side
effects on the boards).

Mounting needs /dev/fuse, libfuse 3 and the ``mfusepy`` module; :func:`fuse_unavailable` says
why not where it cannot be mounted.
"""

from __future__ import annotations

import ctypes
import errno
import importlib.util
import os
import shutil
import stat
import subprocess
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hal.vme import vme_user_abi as abi
from hal.vme.bus import VmeBus
from hal.vme.errors import BusError
from hal.vme.types import AddressModifier, AddressSpace, Width, am_for

GRANULARITY = 0x10000  #: the tsi148's master window granularity


def fuse_unavailable() -> str | None:
    """Why a FUSE stand-in cannot be mounted here, or ``None`` if it can."""
    if not os.path.exists("/dev/fuse"):
        return "no /dev/fuse on this machine"
    if importlib.util.find_spec("mfusepy") is None:
        return "the mfusepy module is not installed (pip install mfusepy)"
    if os.geteuid() != 0 and shutil.which("fusermount3") is None:
        return "not root and no fusermount3"
    try:
        import mfusepy  # noqa: F401
    except (OSError, ImportError) as e:  # libfuse itself missing
        return f"libfuse is not loadable ({e}); apt-get install fuse3 libfuse3-3"
    return None


@dataclass
class WindowState:
    setting: abi.VmeMasterPacked = field(default_factory=abi.VmeMasterPacked)


def am_of(aspace: int, cycle: int) -> AddressModifier:
    space = {abi.VME_A16: AddressSpace.A16, abi.VME_A24: AddressSpace.A24, abi.VME_A32: AddressSpace.A32}[aspace]
    return am_for(space, supervisory=bool(cycle & abi.VME_SUPER), program=bool(cycle & abi.VME_PROG),
                  block=bool(cycle & abi.VME_BLT) and space is not AddressSpace.A16)


class VmeUserFs:
    """The FUSE operations (mfusepy ``Operations``) of the stand-in."""

    use_ns = True

    def __init__(self, bus: VmeBus, layout: abi.Layout = abi.Layout.PACKED) -> None:
        self.bus = bus
        self.layout = layout
        self.windows = {f"/m{i}": WindowState() for i in range(abi.MASTER_WINDOWS)}
        self.irqs: list[tuple[int, int]] = []
        self.calls: dict[str, int] = {"ioctl": 0, "read": 0, "write": 0}
        self.get_nr = abi.vme_get_master(layout)
        self.set_nr = abi.vme_set_master(layout)
        self.irq_nr = abi.vme_irq_gen()

    # --- the file tree -----------------------------------------------------------------
    def getattr(self, path: str, fh: Any = None) -> dict[str, Any]:
        if path == "/":
            return {"st_mode": stat.S_IFDIR | 0o755, "st_nlink": 2}
        if path in self.windows or path == "/ctl":
            return {"st_mode": stat.S_IFREG | 0o660, "st_nlink": 1, "st_size": 1 << 32}
        from mfusepy import FuseOSError
        raise FuseOSError(errno.ENOENT)

    def readdir(self, path: str, fh: Any) -> list[str]:
        return [".", "..", *(p[1:] for p in self.windows), "ctl"]

    def open(self, path: str, fi: Any) -> int:
        fi.direct_io = 1  # no page cache, no read-ahead: every read(2) reaches read() below
        fi.keep_cache = 0
        return 0

    def release(self, path: str, fh: Any) -> int:
        return 0

    def truncate(self, path: str, length: int, fh: Any = None) -> int:
        return 0

    # --- ioctl -------------------------------------------------------------------------
    def ioctl(self, path: str, cmd: int, arg: Any, fh: Any, flags: int, data: Any) -> int:
        from mfusepy import FuseOSError
        self.calls["ioctl"] += 1
        cmd &= 0xFFFFFFFF
        if path == "/ctl":
            if cmd != self.irq_nr:
                raise FuseOSError(errno.EINVAL)
            irq = abi.VmeIrqId.from_buffer_copy(ctypes.string_at(data, ctypes.sizeof(abi.VmeIrqId)))
            if not 1 <= irq.level <= 7:
                raise FuseOSError(errno.EINVAL)
            self.irqs.append((irq.level, irq.statid))
            return 0
        w = self.windows[path]
        struct = self.layout.struct
        size = ctypes.sizeof(struct)
        if cmd == self.get_nr:
            out = struct(enable=w.setting.enable, vme_addr=w.setting.vme_addr, size=w.setting.size,
                         aspace=w.setting.aspace, cycle=w.setting.cycle, dwidth=w.setting.dwidth)
            ctypes.memmove(data, ctypes.addressof(out), size)
            return 0
        if cmd == self.set_nr:
            m = struct.from_buffer_copy(ctypes.string_at(data, size))
            limit = {abi.VME_A16: 1 << 16, abi.VME_A24: 1 << 24, abi.VME_A32: 1 << 32}.get(m.aspace)
            if (limit is None or m.dwidth not in (abi.VME_D16, abi.VME_D32) or m.size == 0
                    or m.vme_addr % GRANULARITY or m.size % GRANULARITY or m.vme_addr + m.size > limit
                    or not m.cycle & (abi.VME_SCT | abi.VME_BLT)):
                raise FuseOSError(errno.EINVAL)
            w.setting = abi.VmeMasterPacked(enable=m.enable, vme_addr=m.vme_addr, size=m.size,
                                            aspace=m.aspace, cycle=m.cycle, dwidth=m.dwidth)
            return 0
        raise FuseOSError(errno.EINVAL)

    # --- data --------------------------------------------------------------------------
    def _chunks(self, offset: int, count: int, dwidth: int) -> list[tuple[int, Width]]:
        out, pos, end = [], offset, offset + count
        while pos < end:
            left = end - pos
            if pos % 4 == 0 and left >= 4 and dwidth >= abi.VME_D32:
                w = Width.D32
            elif pos % 2 == 0 and left >= 2:
                w = Width.D16
            else:
                w = Width.D8
            out.append((pos, w))
            pos += int(w)
        return out

    def _window(self, path: str, offset: int, count: int) -> tuple[abi.VmeMasterPacked, int] | None:
        s = self.windows[path].setting
        if not s.enable or offset >= s.size:
            return None
        return s, min(count, s.size - offset)

    def read(self, path: str, size: int, offset: int, fh: Any) -> bytes:
        from mfusepy import FuseOSError
        self.calls["read"] += 1
        if path == "/ctl":
            return b""
        got = self._window(path, offset, size)
        if got is None:
            return b""
        s, count = got
        am = am_of(s.aspace, s.cycle)
        out = bytearray()
        for pos, w in self._chunks(offset, count, s.dwidth):
            try:
                out += self.bus.read(s.vme_addr + pos, space=am, width=w).to_bytes(int(w), "big")
            except BusError:
                raise FuseOSError(errno.EIO) from None
        return bytes(out)

    def write(self, path: str, data: bytes, offset: int, fh: Any) -> int:
        from mfusepy import FuseOSError
        self.calls["write"] += 1
        if path == "/ctl":
            return 0
        got = self._window(path, offset, len(data))
        if got is None:
            return 0
        s, count = got
        am = am_of(s.aspace, s.cycle)
        for pos, w in self._chunks(offset, count, s.dwidth):
            value = int.from_bytes(data[pos - offset:pos - offset + int(w)], "big")
            try:
                self.bus.write(s.vme_addr + pos, value, space=am, width=w)
            except BusError:
                raise FuseOSError(errno.EIO) from None
        return count


class MountedVmeUser:
    """``with MountedVmeUser(crate, tmp_path) as fs:`` — ``fs.dir`` is the mounted ``/dev/bus/vme``."""

    def __init__(self, bus: VmeBus, where: Path, layout: abi.Layout = abi.Layout.PACKED) -> None:
        self.ops = VmeUserFs(bus, layout)
        self.dir = where / "vme"
        self.dir.mkdir(parents=True, exist_ok=True)
        self._thread: threading.Thread | None = None
        self._error: BaseException | None = None

    def __enter__(self) -> MountedVmeUser:
        import mfusepy

        def serve() -> None:
            try:
                mfusepy.FUSE(self.ops, str(self.dir), raw_fi=True, foreground=True, nothreads=True,
                             fsname="vme_user_standin")
            except BaseException as e:  # reported by __enter__/__exit__
                self._error = e

        self._thread = threading.Thread(target=serve, name="vme-fuse", daemon=True)
        self._thread.start()
        while not os.path.ismount(self.dir):  # wait for the condition itself
            if not self._thread.is_alive():
                raise RuntimeError(f"the FUSE stand-in did not mount at {self.dir}: {self._error!r}")
            time.sleep(0.01)
        return self

    def __exit__(self, *exc: object) -> None:
        tool = shutil.which("fusermount3") or shutil.which("fusermount")
        # lazy: a file a failed test left open cannot keep the mount (and this join) hanging
        cmd = [tool, "-u", "-z", str(self.dir)] if tool else ["umount", "-l", str(self.dir)]
        subprocess.run(cmd, check=False, capture_output=True)
        if self._thread is not None:
            self._thread.join()
