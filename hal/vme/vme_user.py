"""A :class:`~hal.vme.bus.VmeBus` over Linux's VME user interface (``vme_user``).

The kernel's ``vme_user`` driver gives user space four master windows, ``/dev/bus/vme/m0`` …
``m3``, each set with ``ioctl(VME_SET_MASTER, struct vme_master)`` (enable, VME base, size,
address space, cycle, maximum data width) and then read and written at offsets of the window,
plus a control device ``/dev/bus/vme/ctl`` whose only ioctl is ``VME_IRQ_GEN``.

How this backend uses it:

* **Windows.** An access at an address no open window covers takes a free window and sets it
  to the ``window_size``-aligned block (64 KiB by default: the tsi148's granularity) around the
  address, in the access's address space, privilege and program/data kind (one window per
  address modifier), maximum width D32; the setting is read back with ``VME_GET_MASTER`` and a
  window the driver refuses or changes raises :class:`VmeWindowRefused`. With all four in use
  the access raises :class:`VmeWindowsExhausted` unless ``remap=True`` (then the least recently
  used window that is not mmapped is set anew: a syscall per switch, so a loop that needs more
  than four blocks should say so with :meth:`VmeUserBus.open_window` and a larger window).
  A mapped window cannot be set again (the driver answers ``EPERM``): never reconfigured here.
* **Accesses.** ``pread``/``pwrite`` of exactly the access's width at the window offset
  (default), because the bridge drivers (tsi148, ca91cx42) split a transfer by alignment into
  D8/D16/D32 cycles of the size asked, and because a bus error can only be reported through a
  system call (``EIO``, or a short count on older kernels). ``io="mmap"`` maps each window and
  makes single loads/stores of the access's width (``memoryview`` cast to ``B``/``H``/``I``):
  faster, but a failed cycle is invisible or a ``SIGBUS``.
* **Byte order.** The bridge maps VME bytes in address order (byte-invariant): a D32 at ``A``
  is bytes ``A..A+3`` most significant first, the bus's big-endian order.
* **Bus errors.** ``EIO`` or a short transfer raise :class:`~hal.vme.errors.BusError` (cause
  ``REMOTE``: the bridge cannot tell a timeout from a board's BERR*). The tsi148 checks only
  when loaded with ``err_chk=1``; without it a failed read returns whatever the bridge gives —
  all ones on most — so ``all_ones_is_error=True`` turns an all-ones read into a
  ``NO_RESPONDER`` BusError (only for drivers whose registers cannot read all ones).
* **Interrupts.** ``vme_user`` delivers none to user space: drivers poll their status
  registers (:meth:`VmeBus.register_irq_handler` still keeps the table; nothing calls it).
  :meth:`VmeUserBus.generate_irq` raises one on the bus through the control device.
* **Time.** ``now`` is ``time.monotonic`` and ``delay`` sleeps, unless a clock is injected.
"""

from __future__ import annotations

import errno
import fcntl
import mmap
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from hal.vme import vme_user_abi as abi
from hal.vme.bus import VmeBus
from hal.vme.errors import BusError, BusErrorCause, VmeConfigError, VmeError
from hal.vme.types import AddressModifier, VmeValueError, Width

DEFAULT_DEVICE_DIR = "/dev/bus/vme"
DEFAULT_WINDOW_SIZE = 0x10000


class VmeUserError(VmeError):
    """The ``vme_user`` interface could not be used (no device, unknown ABI, ioctl failed)."""


class VmeWindowRefused(VmeConfigError):
    """The driver refused a master window setting, or set something other than what was asked."""


class VmeWindowsExhausted(VmeConfigError):
    """Every master window is in use and none may be set anew."""


class VmeWindowRangeError(VmeError, ValueError):
    """An access reaches past the end of a master window."""


@dataclass(frozen=True)
class WindowSetting:
    """What one ``struct vme_master`` says, in the driver's own bits."""

    enable: bool
    vme_addr: int
    size: int
    aspace: int
    cycle: int
    dwidth: int

    def to_struct(self, layout: abi.Layout) -> abi.VmeMasterStruct:
        return layout.struct(enable=int(self.enable), vme_addr=self.vme_addr, size=self.size,
                             aspace=self.aspace, cycle=self.cycle, dwidth=self.dwidth)

    @classmethod
    def from_struct(cls, s: abi.VmeMasterStruct) -> WindowSetting:
        return cls(bool(s.enable), int(s.vme_addr), int(s.size), int(s.aspace), int(s.cycle), int(s.dwidth))

    @classmethod
    def for_am(cls, am: AddressModifier, vme_addr: int, size: int, dwidth: int = abi.VME_D32) -> WindowSetting:
        return cls(True, vme_addr, size, abi.aspace_bits(am.space.value),
                   abi.cycle_bits(supervisory=am.supervisory, program=am.program, block=am.block), dwidth)

    def __str__(self) -> str:
        state = "enabled" if self.enable else "disabled"
        return (f"{state} vme_addr=0x{self.vme_addr:X} size=0x{self.size:X} aspace=0x{self.aspace:X} "
                f"cycle=0x{self.cycle:X} dwidth=0x{self.dwidth:X}")


def _ioctl_error(op: str, path: str, e: OSError) -> str:
    name = errno.errorcode.get(e.errno or 0, str(e.errno))
    return f"{op} on {path}: {name} ({e.strerror})"


class _PreadAccess:
    """Sized ``pread``/``pwrite`` at window offsets (one system call per access)."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def read(self, offset: int, width: int) -> bytes:
        return os.pread(self.fd, width, offset)

    def write(self, offset: int, data: bytes) -> int:
        return os.pwrite(self.fd, data, offset)

    def close(self) -> None:
        pass


_SWAP = sys.byteorder == "little"


class MmapAccess:
    """Single loads and stores of the access's width in a mapping of a window (or any file).

    ``memoryview.cast`` to ``B``/``H``/``I`` makes CPython load or store exactly 1, 2 or 4 bytes
    at an aligned address; the value is then put into the bus's big-endian order.
    """

    def __init__(self, fd: int, size: int) -> None:
        self.map = mmap.mmap(fd, size, mmap.MAP_SHARED, mmap.PROT_READ | mmap.PROT_WRITE)
        mv = memoryview(self.map)
        self._views = {1: mv.cast("B"), 2: mv.cast("H"), 4: mv.cast("I")}
        self.size = size

    def load(self, offset: int, width: int) -> int:
        raw = int(self._views[width][offset // width])
        return int.from_bytes(raw.to_bytes(width, sys.byteorder), "big") if _SWAP else raw

    def store(self, offset: int, width: int, value: int) -> None:
        raw = int.from_bytes(value.to_bytes(width, "big"), sys.byteorder) if _SWAP else value
        self._views[width][offset // width] = raw

    def read(self, offset: int, width: int) -> bytes:
        return self.load(offset, width).to_bytes(width, "big")

    def write(self, offset: int, data: bytes) -> int:
        self.store(offset, len(data), int.from_bytes(data, "big"))
        return len(data)

    def close(self) -> None:
        for v in self._views.values():
            v.release()
        self.map.close()


@dataclass
class MasterWindow:
    """One of the driver's master windows (``mN``): its fd, setting and access path."""

    index: int
    path: str
    fd: int
    layout: abi.Layout
    setting: WindowSetting | None = None
    am: AddressModifier | None = None
    access: _PreadAccess | MmapAccess | None = None
    last_used: int = 0
    ours: bool = False  #: we enabled it (and disable it on close)
    machine: str = field(default_factory=platform.machine)

    @property
    def mapped(self) -> bool:
        return isinstance(self.access, MmapAccess)

    def covers(self, am: AddressModifier, address: int, width: int) -> bool:
        s = self.setting
        return (s is not None and s.enable and self.am == am
                and s.vme_addr <= address and address + width <= s.vme_addr + s.size)

    def get(self) -> WindowSetting:
        st = self.layout.struct()
        try:
            fcntl.ioctl(self.fd, abi.vme_get_master(self.layout, self.machine), st)  # type: ignore[call-overload]
        except OSError as e:
            raise VmeUserError(_ioctl_error("VME_GET_MASTER", self.path, e)) from e
        return WindowSetting.from_struct(st)

    def set(self, want: WindowSetting) -> WindowSetting:
        """``VME_SET_MASTER``, then read back: raise :class:`VmeWindowRefused` unless it took."""
        if self.mapped:
            raise VmeWindowRefused(f"{self.path} is mapped: the driver cannot set a mapped window anew")
        st = want.to_struct(self.layout)
        try:
            fcntl.ioctl(self.fd, abi.vme_set_master(self.layout, self.machine), st)  # type: ignore[call-overload]
        except OSError as e:
            raise VmeWindowRefused(
                f"{_ioctl_error('VME_SET_MASTER', self.path, e)}: the driver refused {want}"
                + ("; the window is mapped" if e.errno == errno.EPERM else "")
                + ("; the bridge does not support this space/cycle/width/alignment" if e.errno == errno.EINVAL else "")
            ) from e
        got = self.get()
        if want.enable and got != want:
            raise VmeWindowRefused(f"{self.path}: asked for {want}, the driver set {got}")
        self.setting = got
        return got

    def close(self) -> None:
        if self.access is not None:
            self.access.close()
            self.access = None
        try:
            if self.ours and self.setting is not None and self.setting.enable:
                st = WindowSetting(False, self.setting.vme_addr, self.setting.size, self.setting.aspace,
                                   self.setting.cycle, self.setting.dwidth).to_struct(self.layout)
                fcntl.ioctl(self.fd, abi.vme_set_master(self.layout, self.machine), st)  # type: ignore[call-overload]
        except OSError:
            pass  # closing: the window stays as it was, nothing else to do
        finally:
            os.close(self.fd)


def probe_layout(fd: int, path: str, machine: str | None = None) -> abi.Layout:
    """Which ``struct vme_master`` the kernel takes: the layout whose ``VME_GET_MASTER`` works."""
    failures = []
    for layout in (abi.Layout.PACKED, abi.Layout.UNPACKED):
        st = layout.struct()
        try:
            fcntl.ioctl(fd, abi.vme_get_master(layout, machine), st)  # type: ignore[call-overload]
            return layout
        except OSError as e:
            failures.append(f"{layout.value}: {_ioctl_error('VME_GET_MASTER', path, e)}")
    guess = abi.layout_for_kernel(platform.release())
    raise VmeUserError(
        f"{path} answers neither VME_GET_MASTER layout ({'; '.join(failures)}); "
        f"kernel {platform.release()} would be {guess.value if guess else 'unknown'}: "
        "is this a vme_user master window?"
    )


class VmeUserBus(VmeBus):
    """The VME bus of a real crate through ``/dev/bus/vme`` (see the module text).

    Args:
        device_dir: the directory holding ``m0``..``m3`` (and ``ctl``).
        layout: ``"auto"`` (probe with ``VME_GET_MASTER``), ``"packed"``, ``"unpacked"`` or
            ``"kernel"`` (by ``uname -r``; refuses the releases where that is not known).
        window_size: size and alignment of the windows opened on demand.
        io: ``"pread"`` (default) or ``"mmap"``.
        remap: set the least recently used window anew when all four are in use.
        all_ones_is_error: an all-ones read raises a ``NO_RESPONDER`` :class:`BusError`.
        clock, sleep: ``now``/``delay`` (default ``time.monotonic``/``time.sleep``).
    """

    def __init__(
        self,
        device_dir: str | Path = DEFAULT_DEVICE_DIR,
        *,
        layout: str = "auto",
        window_size: int = DEFAULT_WINDOW_SIZE,
        io: str = "pread",
        remap: bool = False,
        all_ones_is_error: bool = False,
        clock: Callable[[], float] = time.monotonic,
        sleep: Callable[[float], None] = time.sleep,
        machine: str | None = None,
    ) -> None:
        super().__init__()
        if window_size <= 0 or window_size & (window_size - 1):
            raise ValueError(f"window size 0x{window_size:X} is not a power of two")
        if io not in ("pread", "mmap"):
            raise ValueError(f"io {io!r}: expected 'pread' or 'mmap'")
        self.device_dir = Path(device_dir)
        self.window_size = window_size
        self.io = io
        self.remap = remap
        self.all_ones_is_error = all_ones_is_error
        self._clock = clock
        self._sleep = sleep
        self.machine = machine or platform.machine()
        self.windows: list[MasterWindow] = []
        self._uses = 0
        self._hot: MasterWindow | None = None
        missing = []
        chosen: abi.Layout | None = None
        for i in range(abi.MASTER_WINDOWS):
            path = str(self.device_dir / f"m{i}")
            try:
                fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)
            except FileNotFoundError:
                missing.append(path)
                continue
            except OSError as e:
                self.close()
                raise VmeUserError(f"cannot open {path}: {e.strerror} (permissions: see docs/vme-user.md)") from e
            if chosen is None:
                try:
                    chosen = self._layout(layout, fd, path)
                except BaseException:
                    os.close(fd)
                    self.close()
                    raise
            self.windows.append(MasterWindow(i, path, fd, chosen, machine=self.machine))
        if not self.windows:
            raise VmeUserError(f"no master window in {self.device_dir} ({', '.join(missing)} missing): "
                               "is the vme_user module loaded with bus=...? (docs/vme-user.md)")
        self.layout: abi.Layout = self.windows[0].layout
        try:
            for w in self.windows:
                w.setting = w.get()
        except BaseException:
            self.close()
            raise

    def _layout(self, layout: str, fd: int, path: str) -> abi.Layout:
        if layout == "auto":
            return probe_layout(fd, path, self.machine)
        if layout == "kernel":
            known = abi.layout_for_kernel(platform.release())
            if known is None:
                raise VmeUserError(f"kernel {platform.release()}: its struct vme_master layout is not known; "
                                   "use layout='auto'")
            return known
        try:
            return abi.Layout(layout)
        except ValueError:
            raise ValueError(f"layout {layout!r}: expected auto, kernel, packed or unpacked") from None

    # --- windows -----------------------------------------------------------------------
    def open_window(self, am: AddressModifier, vme_addr: int, size: int) -> MasterWindow:
        """Set a free window to ``size`` bytes at ``vme_addr`` for ``am`` (or raise)."""
        free = [w for w in self.windows if not (w.setting and w.setting.enable and w.ours)]
        if not free:
            if not self.remap:
                raise VmeWindowsExhausted(self._exhausted_message(am, vme_addr))
            free = sorted((w for w in self.windows if not w.mapped), key=lambda w: w.last_used)
            if not free:
                raise VmeWindowsExhausted(self._exhausted_message(am, vme_addr) + "; all are mapped")
        w = free[0]
        if w.access is not None:
            w.access.close()
            w.access = None
        w.am = None
        w.set(WindowSetting.for_am(am, vme_addr, size))
        w.am, w.ours = am, True
        w.access = MmapAccess(w.fd, size) if self.io == "mmap" else _PreadAccess(w.fd)
        return w

    def _exhausted_message(self, am: AddressModifier, address: int) -> str:
        used = "; ".join(f"m{w.index}: {w.am} 0x{w.setting.vme_addr:X}+0x{w.setting.size:X}"
                         for w in self.windows if w.setting and w.am)
        return (f"no free master window for {am} at 0x{address:X}: all {len(self.windows)} in use ({used}); "
                "open larger windows with open_window() or pass remap=True")

    def _window(self, am: AddressModifier, address: int, width: int) -> MasterWindow:
        w = self._hot
        if w is None or not w.covers(am, address, width):
            for w in self.windows:
                if w.covers(am, address, width):
                    break
            else:
                base = address & ~(self.window_size - 1)
                if address + width > base + self.window_size:
                    raise VmeWindowRangeError(
                        f"{width}-byte access at 0x{address:X} crosses a 0x{self.window_size:X} window")
                w = self.open_window(am, base, min(self.window_size, am.space.size - base))
            self._hot = w
        self._uses += 1
        w.last_used = self._uses
        return w

    def window_read(self, w: MasterWindow, offset: int, width: Width) -> bytes:
        """Read ``width`` bytes at ``offset`` of window ``w`` (typed errors, see the module)."""
        s = w.setting
        if s is None or w.access is None or offset < 0 or offset + int(width) > s.size:
            size = s.size if s else 0
            raise VmeWindowRangeError(f"{w.path}: {width.name} read at offset 0x{offset:X} is past the "
                                      f"window (size 0x{size:X})")
        return w.access.read(offset, int(width))

    # --- VmeBus ------------------------------------------------------------------------
    def now(self) -> float:
        return self._clock()

    def delay(self, seconds: float) -> None:
        if seconds < 0:
            raise ValueError("delay must be >= 0")
        self._sleep(seconds)

    def _read(self, am: AddressModifier, address: int, width: Width) -> int:
        w = self._window(am, address, int(width))
        offset = address - w.setting.vme_addr  # type: ignore[union-attr]
        try:
            data = w.access.read(offset, int(width))  # type: ignore[union-attr]
        except OSError as e:
            raise self._berr(e, am, address, width, write=False) from e
        if len(data) != int(width):
            raise BusError(address, am, width, BusErrorCause.REMOTE,
                           f"vme_user: {w.path} read {len(data)} of {int(width)} bytes (a bus error, reported "
                           "as a short transfer)")
        value = int.from_bytes(data, "big")
        if self.all_ones_is_error and value == width.max_value:
            raise BusError(address, am, width, BusErrorCause.NO_RESPONDER,
                           "read all ones, taken as a bus error (all_ones_is_error)")
        return value

    def _write(self, am: AddressModifier, address: int, width: Width, value: int) -> None:
        w = self._window(am, address, int(width))
        offset = address - w.setting.vme_addr  # type: ignore[union-attr]
        try:
            n = w.access.write(offset, value.to_bytes(int(width), "big"))  # type: ignore[union-attr]
        except OSError as e:
            raise self._berr(e, am, address, width, write=True) from e
        if n != int(width):
            raise BusError(address, am, width, BusErrorCause.REMOTE,
                           f"vme_user: {w.path} wrote {n} of {int(width)} bytes (a bus error, reported as a "
                           "short transfer)", write=True)

    @staticmethod
    def _berr(e: OSError, am: AddressModifier, address: int, width: Width, *, write: bool) -> VmeError:
        if e.errno == errno.EIO:
            return BusError(address, am, width, BusErrorCause.REMOTE,
                            "vme_user: EIO (the bridge saw BERR* or a bus timeout)", write=write)
        return VmeUserError(f"vme_user {'write' if write else 'read'} at 0x{address:X}: {e}")

    # --- interrupts --------------------------------------------------------------------
    def generate_irq(self, level: int, statid: int) -> None:
        """Raise interrupt ``level`` (1..7) with vector ``statid`` on the bus (``VME_IRQ_GEN``)."""
        if not 1 <= level <= 7 or not 0 <= statid <= 0xFF:
            raise ValueError(f"IRQ level {level} must be 1..7 and vector {statid} 0..255")
        path = str(self.device_dir / abi.CONTROL_DEVICE)
        irq = abi.VmeIrqId(level=level, statid=statid)
        try:
            fd = os.open(path, os.O_RDWR | os.O_CLOEXEC)
        except OSError as e:
            raise VmeUserError(f"cannot open {path}: {e.strerror}") from e
        try:
            fcntl.ioctl(fd, abi.vme_irq_gen(self.machine), irq)  # type: ignore[call-overload]
        except OSError as e:
            raise VmeUserError(_ioctl_error("VME_IRQ_GEN", path, e)) from e
        finally:
            os.close(fd)

    # --- lifetime ----------------------------------------------------------------------
    def describe(self) -> list[dict[str, str]]:
        return [{"window": w.path, "layout": w.layout.value, "am": str(w.am) if w.am else "-",
                 "setting": str(w.setting) if w.setting else "-", "io": self.io} for w in self.windows]

    def close(self) -> None:
        """Disable the windows this bus set, unmap and close them."""
        windows, self.windows, self._hot = self.windows, [], None
        for w in windows:
            w.close()

    def __enter__(self) -> VmeUserBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def parse_bus_spec(text: str) -> str:
    """``vme_user`` or ``vme_user:/dev/bus/vme`` → the device directory."""
    name, _, rest = text.partition(":")
    if name != "vme_user":
        raise VmeValueError(f"bus {text!r}: expected 'emulated', 'vme_user' or 'vme_user:DIR'")
    return rest or DEFAULT_DEVICE_DIR


__all__ = [
    "DEFAULT_DEVICE_DIR",
    "MasterWindow",
    "MmapAccess",
    "VmeUserBus",
    "VmeUserError",
    "VmeWindowRangeError",
    "VmeWindowRefused",
    "VmeWindowsExhausted",
    "WindowSetting",
    "parse_bus_spec",
    "probe_layout",
]
