"""What the red team saw end in exit 3 ("unexpected error") or accepted silently: each is now
refused as bad input, in one line, before anything is built (#30, "Exit 3 where a typed error
belongs")."""

from __future__ import annotations

import pytest

from vmehil.cli import main


@pytest.mark.parametrize(("fault", "says"), [
    ("pot_open@1e308:joint=j1", "at_s: expected a time in seconds in [0, 86400]"),  # was OverflowError
    ("adc_noise:joint=j1,signal=encoder", "adc_noise acts on a board of type 'adc'; j1's encoder is on quad0"),
    ("adc_noise:board=dac0", "adc_noise acts on a board of type 'adc'; it names dac0 (type 'dac')"),
    ("pot_open:joint=j1,joint=j2", "joint: expected one value (the key is given twice)"),
    ("adc_noise:joint=j1,rms_v=-1", "rms_v: expected a finite number >= 0"),
    ("encoder_glitch:joint=j1,counts=-5", "counts: expected an integer >= 0"),
    ("encoder_glitch:joint=j1,intervals=0", "intervals: expected an integer >= 1"),
    ("can_frame_loss:percent=150", "percent: expected a finite number in [0, 100]"),
])
def test_a_fault_the_rig_cannot_take_is_refused_before_the_run(fault, says, capsys) -> None:
    assert main(["run", "--duration", "0.1", "--quiet", "--fault", fault]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if not line.startswith("warning:")]
    assert len(err) == 1 and says in err[0], err


@pytest.mark.parametrize(("argv", "says"), [
    (["--duration", "1e-9"], "shorter than one servo period (8 ms)"),
    (["--gains", ",,,"], "names no gain"),
])
def test_a_run_that_would_do_nothing_is_refused(argv, says, capsys) -> None:
    assert main(["run", "--quiet", *argv]) == 2
    assert says in capsys.readouterr().err


def test_a_margin_that_is_not_a_number_is_refused(capsys) -> None:
    # --mavlink-min-margin nan made every live gain change refused
    with pytest.raises(SystemExit) as stop:
        main(["run", "--mavlink", "udpin:127.0.0.1:14999", "--mavlink-min-margin", "nan"])
    assert stop.value.code == 2 and "--mavlink-min-margin" in capsys.readouterr().err


def test_a_driver_that_fails_while_the_real_rig_is_set_up_refuses_the_rig() -> None:
    # an ADC that never finishes, a short write: "unexpected error" (3) or bad input (2), not "refused"
    from hal.vme.errors import BusError, BusErrorCause
    from tests.support.bus_trace import RecordingBus
    from vmehil.rig_setup.real_bus import RealBusRefused, prepare_real_rig
    from vmehil.rig_setup.system import build_emulated_rig

    system = build_emulated_rig("jpl-arm", seed=0)

    class ShortWrites(RecordingBus):
        def _write(self, am, address, width, value):  # every write fails, as a short write(2) does
            raise BusError(address, am, width, BusErrorCause.REMOTE, write=True)

    try:
        with pytest.raises(RealBusRefused, match="setting up the drivers failed, nothing enabled: BusError"):
            prepare_real_rig(system.rig, ShortWrites(system.crate))
    finally:
        system.close()


def test_a_local_cluster_whose_worker_dies_while_it_starts_is_an_engine_error(monkeypatch) -> None:
    distributed = pytest.importorskip("distributed")
    from vmehil.analysis.dask_engine import DaskEngine
    from vmehil.analysis.parallel import EngineError

    def nanny_fails(*a, **kw):
        raise RuntimeError("Nanny failed to start.")

    monkeypatch.setattr(distributed, "LocalCluster", nanny_fails)
    with pytest.raises(EngineError, match="Nanny failed to start"):
        DaskEngine(jobs=1).open()
