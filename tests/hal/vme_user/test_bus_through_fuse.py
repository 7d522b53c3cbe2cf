"""VmeUserBus through real open/ioctl/pread/pwrite calls on a FUSE stand-in for /dev/bus/vme
(tests/support/vme_fuse.py) forwarding to an emulated crate; and the mmap path on a plain file."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import pytest

from emulators.crate import Crate
from emulators.ram import RamBoard
from hal.vme import AddressSpace, BusError, BusErrorCause, Width, am_for
from hal.vme import vme_user_abi as abi
from hal.vme.vme_user import (
    MmapAccess,
    VmeUserBus,
    VmeUserError,
    VmeWindowRangeError,
    VmeWindowRefused,
    VmeWindowsExhausted,
    parse_bus_spec,
)
from tests.support.vme_fuse import MountedVmeUser, fuse_unavailable

A24 = AddressSpace.A24


def _crate() -> Crate:
    crate = Crate()
    crate.install(RamBoard("ram", size=0x1000), base=0x200000, space="A24")
    crate.install(RamBoard("ram16", size=0x100), base=0x4000, space="A16")
    return crate


@pytest.fixture
def mounted(tmp_path: Path) -> Iterator[tuple[Crate, MountedVmeUser]]:
    why = fuse_unavailable()
    if why:
        pytest.skip(f"FUSE stand-in cannot be mounted: {why}")
    crate = _crate()
    with MountedVmeUser(crate, tmp_path) as fs:
        yield crate, fs


def test_accesses_reach_the_boards_in_big_endian_order(mounted) -> None:
    crate, fs = mounted
    with VmeUserBus(fs.dir, clock=crate.now, sleep=crate.delay) as bus:
        bus.write(0x200010, 0x12345678, space=A24, width=Width.D32)
        assert crate.read(0x200010, space=A24, width=Width.D16) == 0x1234  # most significant first
        assert bus.read(0x200012, space=A24, width=Width.D16) == 0x5678
        assert bus.read(0x200013, space=A24, width=Width.D8) == 0x78
        bus.write(0x4002, 0xBEEF, space=AddressSpace.A16, width=Width.D16)
        assert crate.read(0x4002, space=AddressSpace.A16, width=Width.D16) == 0xBEEF
        ams = {w["am"] for w in bus.describe()}
    assert str(am_for(A24)) in ams and str(am_for(AddressSpace.A16)) in ams
    assert fs.ops.calls["read"] >= 2 and fs.ops.calls["ioctl"] >= 4


def test_each_read_is_one_cycle_on_the_board(mounted) -> None:
    """direct_io: no read-ahead, no cache — a read has side effects, so it must reach the crate once."""
    crate, fs = mounted
    with VmeUserBus(fs.dir) as bus:
        before = crate.counters["read.A24.D16"]
        for _ in range(5):
            bus.read(0x200000, space=A24, width=Width.D16)
        assert crate.counters["read.A24.D16"] - before == 5


def test_the_layout_is_probed(tmp_path: Path) -> None:
    why = fuse_unavailable()
    if why:
        pytest.skip(f"FUSE stand-in cannot be mounted: {why}")
    crate = _crate()
    with MountedVmeUser(crate, tmp_path, layout=abi.Layout.UNPACKED) as fs:
        with VmeUserBus(fs.dir) as bus:
            assert bus.layout is abi.Layout.UNPACKED
            bus.write(0x200000, 0xA5, space=A24, width=Width.D8)
            assert crate.read(0x200000, space=A24, width=Width.D8) == 0xA5
        with pytest.raises(VmeUserError, match="VME_GET_MASTER.*EINVAL"):  # the other layout's number
            VmeUserBus(fs.dir, layout="packed")


def test_a_window_the_driver_refuses_is_a_typed_error(mounted) -> None:
    _, fs = mounted
    with VmeUserBus(fs.dir, window_size=0x1000) as bus:  # below the bridge's 64 KiB granularity
        with pytest.raises(VmeWindowRefused, match="refused"):
            bus.read(0x200000, space=A24, width=Width.D16)


def test_a_missing_board_is_a_bus_error(mounted) -> None:
    _, fs = mounted
    with VmeUserBus(fs.dir) as bus:
        with pytest.raises(BusError) as e:
            bus.read(0x300000, space=A24, width=Width.D16)
        assert e.value.cause is BusErrorCause.REMOTE and "EIO" in str(e.value)
        with pytest.raises(BusError):
            bus.write(0x300000, 1, space=A24, width=Width.D16)


def test_all_ones_can_be_taken_as_a_bus_error(mounted) -> None:
    crate, fs = mounted
    crate.write(0x200020, 0xFFFF, space=A24, width=Width.D16)
    with VmeUserBus(fs.dir) as bus:
        assert bus.read(0x200020, space=A24, width=Width.D16) == 0xFFFF
    with VmeUserBus(fs.dir, all_ones_is_error=True) as bus:
        with pytest.raises(BusError) as e:
            bus.read(0x200020, space=A24, width=Width.D16)
        assert e.value.cause is BusErrorCause.NO_RESPONDER


def test_access_past_a_window_is_refused(mounted) -> None:
    _, fs = mounted
    with VmeUserBus(fs.dir) as bus:
        w = bus.open_window(am_for(A24), 0x200000, 0x10000)
        with pytest.raises(VmeWindowRangeError, match="past the window"):
            bus.window_read(w, 0xFFFF, Width.D16)
        assert bus.window_read(w, 0xFFE, Width.D16) == b"\x00\x00"  # the RAM ends at 0x1000
        # the driver itself: a read at the window's end reads nothing
        assert os.pread(w.fd, 2, 0x10000) == b""


def test_four_windows_then_a_clear_error_or_reuse(mounted) -> None:
    _, fs = mounted
    with VmeUserBus(fs.dir) as bus:
        for i in range(4):
            bus.read(0x200000 + i * 0x10000, space=A24, width=Width.D8) if i == 0 else None
            if i:
                with pytest.raises(BusError):  # nobody there, but the window is taken
                    bus.read(0x200000 + i * 0x10000, space=A24, width=Width.D8)
        with pytest.raises(VmeWindowsExhausted, match="all 4 in use"):
            bus.read(0x4000, space=AddressSpace.A16, width=Width.D16)
    with VmeUserBus(fs.dir, remap=True) as bus:
        for i in range(1, 4):
            with pytest.raises(BusError):
                bus.read(0x200000 + i * 0x10000, space=A24, width=Width.D8)
        bus.write(0x200000, 7, space=A24, width=Width.D8)
        bus.write(0x4000, 0x1234, space=AddressSpace.A16, width=Width.D16)  # takes the least recently used
        assert bus.read(0x200000, space=A24, width=Width.D8) == 7
        assert bus.read(0x4000, space=AddressSpace.A16, width=Width.D16) == 0x1234


def test_closing_disables_the_windows_it_set(mounted) -> None:
    _, fs = mounted
    bus = VmeUserBus(fs.dir)
    bus.read(0x200000, space=A24, width=Width.D16)
    bus.close()
    assert not any(w.setting.enable for w in fs.ops.windows.values())


def test_irq_generation_goes_through_the_control_device(mounted) -> None:
    _, fs = mounted
    with VmeUserBus(fs.dir) as bus:
        bus.generate_irq(3, 0x42)
        with pytest.raises(ValueError):
            bus.generate_irq(0, 0x42)
    assert fs.ops.irqs == [(3, 0x42)]


def test_no_device_directory_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(VmeUserError, match="no master window"):
        VmeUserBus(tmp_path)


def test_a_file_that_is_not_a_window_is_refused(tmp_path: Path) -> None:
    (tmp_path / "m0").write_bytes(b"\0" * 64)
    with pytest.raises(VmeUserError, match="neither VME_GET_MASTER layout"):
        VmeUserBus(tmp_path)


def test_bus_spec() -> None:
    assert parse_bus_spec("vme_user") == "/dev/bus/vme"
    assert parse_bus_spec("vme_user:/tmp/x") == "/tmp/x"
    with pytest.raises(ValueError):
        parse_bus_spec("vmeuser")


def test_mmap_path_makes_sized_big_endian_accesses(tmp_path: Path) -> None:
    """The mmap path cannot go through FUSE (no shared mappings of direct_io files): a plain file."""
    f = tmp_path / "window"
    f.write_bytes(bytes(range(16)) + b"\0" * (4096 - 16))
    fd = os.open(f, os.O_RDWR)
    try:
        m = MmapAccess(fd, 4096)
        assert m.load(0, 4) == 0x00010203 and m.load(2, 2) == 0x0203 and m.load(5, 1) == 5
        m.store(8, 4, 0xDEADBEEF)
        m.store(12, 2, 0x1234)
        m.close()
    finally:
        os.close(fd)
    assert f.read_bytes()[8:14] == bytes.fromhex("DEADBEEF1234")
