"""`vmehil unit --fault/--faults/--calibration` (docs/melmalec.md): a unit controller process takes
the faults of its own joints and boards, at the tick the single run would; a fault it cannot take
(another unit's, the plant's) is refused before it joins the run. Threads on the `virtual` unit
bus stand in for the processes here (the same run_unit)."""

from __future__ import annotations

import itertools
from pathlib import Path

import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from tests.vmehil.test_units_remote import UNITS, start_units
from vmehil.cli import main
from vmehil.commands.unit_coordinate import unit_faults
from vmehil.fault_scenarios.options import FaultOptions
from vmehil.unit_controllers.processes import run_coordinator
from vmehil.unit_controllers.remote import unit_bus

RIG = load_rig(resolve_rig("melmalec-16"))
_channels = itertools.count()


@pytest.mark.parametrize(("fault", "says"), [
    ("amp_fault_line@0.4:joint=leg3_knee", "give it to `vmehil unit --unit leg3`"),
    ("pot_frozen@0.2:joint=leg1_knee", "pot_frozen is a fault of the plant"),
    ("no_such_fault:joint=leg1_knee", "no_such_fault"),
])
def test_a_fault_the_unit_cannot_take_is_refused_before_it_joins_the_run(fault, says, capsys) -> None:
    # no coordinator runs: a unit that went on to join would wait --start-timeout, then be refused
    status = main(["unit", "--rig", "melmalec-16", "--unit", "leg1", "--start-timeout", "0.01", "--fault", fault])
    assert status == 2
    assert says in capsys.readouterr().err


def test_a_units_own_board_fault_stops_it_at_the_single_runs_tick_and_every_unit_with_it() -> None:
    """amp_fault_line on leg3_knee (pio2, leg3's PIO) at 0.4 s, given to `vmehil unit --unit
    leg3`: leg3 stops in tick 50 on `amplifier_fault`, as the single run and `--units parallel`
    do (test_units_options), and every other unit stops at the end of that tick (the answer to
    its exchange carries the stop), its final stop verified."""
    before_run, faults = unit_faults("leg3", FaultOptions(specs=("amp_fault_line@0.4:joint=leg3_knee",)), RIG)
    assert [f.kind.name for f in faults] == ["amp_fault_line"]
    channel = f"unit-faults-{next(_channels)}"
    results, threads = start_units(RIG, channel, per_unit={"leg3": {"before_run": before_run}})
    bus = unit_bus("virtual", channel)
    try:
        out = run_coordinator(RIG, bus, seed=6, n_ticks=75, timeout_s=5.0, start_timeout_s=20.0)
    finally:
        bus.close()
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    leg3 = results["leg3"]
    assert (leg3.loop.fault.cause, leg3.loop.fault.tick) == ("amplifier_fault", 50)
    for name in UNITS:
        r = results[name]
        assert not isinstance(r, BaseException), (name, r)
        assert r.loop.final_stop["verified"], name
        if name != "leg3":  # told in the answer to exchange 50, the exchange that ends tick 50
            assert (r.loop.fault.cause, r.loop.fault.tick) == ("unit_stop", 51), (name, r.loop.fault)
    assert out.stop is not None and out.stop.unit == "leg3"


def test_units_on_the_unit_bus_read_through_the_calibration_file_as_the_single_run() -> None:
    """`vmehil unit --calibration`: each unit's drivers apply the file's entries for their own
    joints and boards (a pot table on leg2_lift, an offset on the arm's ADC), so the units'
    readings equal the single run's with the same file, bit for bit — and differ from nominal."""
    import tempfile

    import numpy as np

    from servo.runner import LockstepRunner
    from tests.vmehil.test_units_options import _calibration_file
    from tests.vmehil.test_units_remote import merged
    from vmehil.calibration.store import load_store
    from vmehil.rig_setup.session import build_loop
    from vmehil.rig_setup.system import build_emulated_rig

    n = 20
    with tempfile.TemporaryDirectory() as tmp:
        store = load_store(_calibration_file(Path(tmp)), RIG)

    def single(calibration) -> np.ndarray:
        system = build_emulated_rig(RIG, seed=3, calibration=calibration)
        loop = build_loop(system, n_ticks=n)
        with loop.armed():
            LockstepRunner(system, loop).run(n)
        system.close()
        return loop.recorder.trimmed()["theta_pot"]

    channel = f"unit-calibration-{next(_channels)}"
    results, threads = start_units(RIG, channel, calibration=store)
    bus = unit_bus("virtual", channel)
    try:
        run_coordinator(RIG, bus, seed=3, n_ticks=n, timeout_s=5.0, start_timeout_s=20.0)
    finally:
        bus.close()
    for t in threads:
        t.join(timeout=60)
    units = merged(RIG, results, "theta_pot", n)
    assert np.array_equal(units, single(store), equal_nan=True)
    assert not np.array_equal(units, single(None), equal_nan=True)
