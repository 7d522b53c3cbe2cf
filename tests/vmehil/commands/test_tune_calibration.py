"""The simulating `vmehil tune` analyses load the drivers' calibration as `vmehil run` does, say
which file they used, and ship it with every run (it was ignored: 1.14° of static error on the true
angle in a calibrated directory)."""

from __future__ import annotations

import pickle

import pytest

from emulators.presets import resolve_rig
from servo.rig import load_rig
from vmehil.analysis.rigparams import load_joint
from vmehil.analysis.simulate import SimSettings, simulate
from vmehil.calibration.store import CalibrationStore
from vmehil.commands import tune
from vmehil.commands.tune import TuneOptions
from vmehil.rig_setup import system as system_module


@pytest.fixture
def calibrated_dir(tmp_path, monkeypatch):
    """A calibration directory holding jpl-arm's file (an empty calibration: a valid, loadable file)."""
    rig = load_rig(resolve_rig("jpl-arm"))
    path = CalibrationStore.empty(rig).save(tmp_path / "jpl-arm.toml")
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path))
    return path


def test_the_simulations_take_the_rigs_calibration_file_and_say_so(calibrated_dir, capsys) -> None:
    jp = load_joint("jpl-arm", 1)
    settings = tune._sim_settings(TuneOptions(tune_cmd="step"), jp, allow_short=True)
    assert settings.calibration is not None and settings.calibration.path == calibrated_dir
    assert f"calibration: {calibrated_dir}" in capsys.readouterr().err
    # it travels with the run as data: a worker process or a Dask worker reads no file
    assert pickle.loads(pickle.dumps(settings)).calibration.rig == "jpl-arm"


def test_without_a_file_the_simulations_say_they_use_nominal_values(tmp_path, monkeypatch, capsys) -> None:
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "none"))
    settings = tune._sim_settings(TuneOptions(tune_cmd="step"), load_joint("jpl-arm", 1), allow_short=True)
    assert settings.calibration is None
    assert "drivers use nominal values" in capsys.readouterr().err


def test_a_simulation_builds_its_rig_with_the_calibration_it_was_given(calibrated_dir, monkeypatch) -> None:
    seen = []
    real = system_module.build_emulated_rig

    def spy(*a, **kw):
        seen.append(kw.get("calibration"))
        return real(*a, **kw)

    monkeypatch.setattr(system_module, "build_emulated_rig", spy)
    store = CalibrationStore.empty(load_rig(resolve_rig("jpl-arm")))
    simulate(load_joint("jpl-arm", 1), settings=SimSettings(move_deg=1.0, hold_s=0.2, allow_short=True,
                                                            calibration=store), traces=False)
    assert seen == [store]
