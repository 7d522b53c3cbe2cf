"""Shared fixtures. Tests are deterministic: every random source is seeded."""

from __future__ import annotations

import os

import pytest
from hypothesis import settings

from emulators.crate import Crate
from emulators.ram import RamBoard

# Property tests are derandomized: the same examples on every run and every machine, so CI
# cannot fail on an example nobody has seen (set HYPOTHESIS_PROFILE=explore to search afresh).
settings.register_profile("deterministic", derandomize=True, deadline=None, print_blob=True)
settings.register_profile("explore", deadline=None, print_blob=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "deterministic"))


@pytest.fixture
def crate() -> Crate:
    """A crate with RAM boards in each address space."""
    c = Crate("test")
    c.install(RamBoard("ram16", 0x100), base=0x1000, space="A16", slot=2)
    c.install(RamBoard("ram24", 0x10000), base=0x200000, space="A24", slot=3)
    c.install(RamBoard("ram32", 0x10000), base=0x80000000, space="A32", slot=4)
    return c
