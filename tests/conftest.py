"""Shared fixtures. Tests are deterministic: every random source is seeded."""

from __future__ import annotations

import os
import signal
import sys
import textwrap
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path

import pytest
from hypothesis import settings

from emulators.crate import Crate
from emulators.ram import RamBoard

# Property tests are derandomized: the same examples on every run and every machine, so CI
# cannot fail on an example nobody has seen (set HYPOTHESIS_PROFILE=explore to search afresh).
settings.register_profile("deterministic", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))

# The tests that send SIGINT to a `vmehil` process need it to act on SIGINT. A shell that starts
# pytest in the background (`make test &`, `( … & )`) hands it SIGINT ignored, and an ignored
# signal stays ignored across exec, so those processes would never see their Ctrl-C and run on
# to a normal end. A handler (unlike SIG_IGN) is reset to the default at exec: the children then
# start with SIGINT as a terminal's foreground job has it, wherever pytest was launched from.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# Every `vmehil run` writes its black box when it stops (docs/scope.md, "Black box"): with no
# report directory into ./vmehil-blackbox of the working directory. The suite's runs (in-process
# and the processes they start, which inherit this) write none unless a test asks with --blackbox;
# the box is still kept on every tick (servo.blackbox).
os.environ.setdefault("VMEHIL_BLACKBOX", "off")


def pytest_collection_finish(session: pytest.Session) -> None:
    """Python ignores SIGPIPE (a write to a closed pipe raises BrokenPipeError); a library that
    resets it to the default when imported (vcdvcd does) would let such a write kill the whole
    pytest process (CI: exit 243, no report). Every test module is imported by now: put it back."""
    if signal.getsignal(signal.SIGPIPE) is not signal.SIG_IGN:
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)


@pytest.fixture
def crate() -> Crate:
    """A crate with RAM boards in each address space."""
    c = Crate("test")
    c.install(RamBoard("ram16", 0x100), base=0x1000, space="A16", slot=2)
    c.install(RamBoard("ram24", 0x10000), base=0x200000, space="A24", slot=3)
    c.install(RamBoard("ram32", 0x10000), base=0x80000000, space="A32", slot=4)
    return c


InstallDistribution = Callable[[str, Mapping[str, str], Mapping[str, Mapping[str, str]]], Path]


@pytest.fixture
def install_distribution(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[InstallDistribution]:
    """``install(dist, modules, entry_points)``: a third-party distribution installed for this test
    only, as pip leaves one — its modules (``{name: source}``) and a ``.dist-info`` declaring
    ``{group: {name: "module:attr"}}`` on ``sys.path``. The plug-in tables read it on their next
    look-up; it is gone after the test."""
    from emulators.board_types import BOARD_TYPES
    from hal.board_types import BOARD_TYPES as DRIVER_BOARD_TYPES
    from servo.control.objects import CONTROL_OBJECTS
    from vmehil.calibration.procedures import PROCEDURES

    tables = (BOARD_TYPES, DRIVER_BOARD_TYPES, CONTROL_OBJECTS, PROCEDURES)
    modules_added: list[str] = []

    def install(dist: str, modules: Mapping[str, str], entry_points: Mapping[str, Mapping[str, str]]) -> Path:
        root = tmp_path / f"site-{dist}"
        info = root / f"{dist}-1.0.dist-info"
        info.mkdir(parents=True)
        for name, source in modules.items():
            (root / f"{name}.py").write_text(textwrap.dedent(source))
            modules_added.append(name)
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 1.0\n")
        (info / "entry_points.txt").write_text("".join(
            f"[{group}]\n" + "".join(f"{name} = {value}\n" for name, value in eps.items())
            for group, eps in entry_points.items()))
        monkeypatch.syspath_prepend(str(root))  # also invalidates the import system's caches
        for table in tables:
            table.refresh()
        return root

    yield install
    for name in modules_added:
        sys.modules.pop(name, None)
    for table in tables:  # sys.path is restored after this; the next look-up reads it afresh
        table.refresh()
