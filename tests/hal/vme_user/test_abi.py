"""The Python side of the vme_user ABI against the vendored C definitions, compiled here."""

from __future__ import annotations

import ctypes
import platform
import shutil
import subprocess
from pathlib import Path

import pytest

from hal.vme import vme_user_abi as abi

HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def c_facts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, int]:
    cc = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if cc is None:
        pytest.skip("no C compiler (cc/gcc/clang) on this machine")
    exe = tmp_path_factory.mktemp("abi") / "abi_dump"
    subprocess.run([cc, "-Wall", "-Werror", "-o", str(exe), str(HERE / "abi_dump.c")], check=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    return {k: int(v) for k, v in (line.split() for line in out.splitlines())}


@pytest.mark.parametrize("layout", list(abi.Layout))
def test_struct_vme_master_matches_the_c_layout(c_facts: dict[str, int], layout: abi.Layout) -> None:
    tag = layout.value
    assert ctypes.sizeof(layout.struct) == c_facts[f"{tag}.sizeof"]
    for name in ("enable", "vme_addr", "size", "aspace", "cycle", "dwidth"):
        assert getattr(layout.struct, name).offset == c_facts[f"{tag}.{name}"], name


@pytest.mark.parametrize("layout", list(abi.Layout))
def test_request_numbers_match_the_c_macros(c_facts: dict[str, int], layout: abi.Layout) -> None:
    assert abi.vme_get_master(layout) == c_facts[f"{layout.value}.get"]
    assert abi.vme_set_master(layout) == c_facts[f"{layout.value}.set"]
    assert abi.vme_irq_gen() == c_facts["irq_gen"]
    assert ctypes.sizeof(abi.VmeIrqId) == c_facts["irq_id.sizeof"]


def test_attribute_bits_match_vme_h(c_facts: dict[str, int]) -> None:
    for name in ("A16", "A24", "A32", "SCT", "BLT", "SUPER", "USER", "PROG", "DATA", "D8", "D16", "D32"):
        assert getattr(abi, f"VME_{name}") == c_facts[name], name


@pytest.mark.skipif(platform.machine() != "x86_64", reason="the literal numbers are x86-64's")
def test_the_two_layouts_differ_in_size_and_request_number_on_x86_64() -> None:
    assert ctypes.sizeof(abi.VmeMasterUnpacked) == 40 and ctypes.sizeof(abi.VmeMasterPacked) == 32
    assert abi.vme_get_master(abi.Layout.PACKED) == 0x8020AE03
    assert abi.vme_set_master(abi.Layout.PACKED) == 0x4020AE04
    assert abi.vme_get_master(abi.Layout.UNPACKED) == 0x8028AE03
    assert abi.vme_set_master(abi.Layout.UNPACKED) == 0x4028AE04
    assert abi.vme_irq_gen() == 0x4002AE05


def test_powerpc_encodes_direction_in_three_bits() -> None:
    """A VME host is often a PowerPC board: its _IOC puts READ=2/WRITE=4 in 3 bits over a 13-bit size."""
    assert abi.ioc("r", 3, 32, machine="ppc") == (2 << 29) | (32 << 16) | (0xAE << 8) | 3
    assert abi.ioc("w", 4, 32, machine="ppc") == (4 << 29) | (32 << 16) | (0xAE << 8) | 4
    assert abi.ioc("r", 3, 32, machine="aarch64") == abi.ioc("r", 3, 32, machine="x86_64")


@pytest.mark.parametrize(("release", "layout"), [
    ("6.18.44-fc", abi.Layout.PACKED), ("3.18.0", abi.Layout.PACKED), ("4.9.227", abi.Layout.PACKED),
    ("3.10.108", abi.Layout.UNPACKED), ("2.6.32-5", abi.Layout.UNPACKED), ("3.14.1", None), ("junk", None),
])
def test_layout_by_kernel_release(release: str, layout: abi.Layout | None) -> None:
    assert abi.layout_for_kernel(release) is layout
