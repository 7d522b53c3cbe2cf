"""collector_spared (vmehil.analysis.batch): the cyclic collector is off while a batch's runs are
built, back on with the built objects frozen out of its scans for the ticks, and as it was at
the end (nothing left frozen), however the block ends."""

from __future__ import annotations

import gc

import pytest

from vmehil.analysis.batch import collector_spared


@pytest.fixture(autouse=True)
def _collector_restored():
    was = gc.isenabled()
    gc.enable()
    yield
    gc.unfreeze()
    if not was:
        gc.disable()


def test_the_collector_is_off_while_building_and_on_with_the_build_frozen_after_built() -> None:
    assert gc.get_freeze_count() == 0
    with collector_spared() as built:
        assert not gc.isenabled()
        kept = [[i] for i in range(1000)]  # objects that live as long as the batch
        built()
        assert gc.isenabled()
        assert gc.get_freeze_count() >= len(kept)
        built()  # a second call changes nothing
        assert gc.isenabled()
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0


def test_an_error_in_the_build_restores_the_collector_and_freezes_nothing() -> None:
    with pytest.raises(RuntimeError), collector_spared():
        assert not gc.isenabled()
        raise RuntimeError("a run could not be built")
    assert gc.isenabled()
    assert gc.get_freeze_count() == 0


def test_a_collector_that_was_off_stays_off() -> None:
    gc.disable()
    with collector_spared() as built:
        built()
        assert not gc.isenabled()
        assert gc.get_freeze_count() > 0
    assert not gc.isenabled()
    assert gc.get_freeze_count() == 0
