"""`vmehil tune --velocity-filter-hz` and a rig file's [joint.servo.velocity_filter]: the tuning
model takes the servo's filter (docs/control.md, "The velocity filter alternative to KvI")."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.support.rig_variants import rig_with
from vmehil.cli import main


def _bode(tmp_path: Path, *args: str) -> dict:
    path = tmp_path / "bode.json"
    assert main(["tune", "bode", "--json", str(path), *args]) == 0
    return json.loads(path.read_text())


def test_bode_models_the_filter_the_option_names(tmp_path, capsys):
    plain = _bode(tmp_path)
    filt = _bode(tmp_path, "--velocity-filter-hz", "5")
    assert plain["kvi_filter_hz"] is None and filt["kvi_filter_hz"] == 5.0
    # above the corner the KvI channel rolls off: less loop gain, a lower crossover
    assert filt["sampled"]["crossover_hz"] < plain["sampled"]["crossover_hz"]
    assert "low-passed at 5 Hz" in capsys.readouterr().out


def test_the_rigs_filter_is_modelled_and_the_option_turns_it_off(tmp_path, capsys):
    rig = rig_with(tmp_path, "", joint=1, servo_extra="velocity_filter = { cutoff_hz = 5.0 }")
    from_rig = _bode(tmp_path, "--rig", str(rig))
    assert from_rig["kvi_filter_hz"] == 5.0
    off = _bode(tmp_path, "--rig", str(rig), "--velocity-filter-hz", "0")
    assert off["kvi_filter_hz"] is None
    assert off["sampled"]["crossover_hz"] == _bode(tmp_path)["sampled"]["crossover_hz"]


def test_limit_cycle_prediction_with_the_filter_finds_no_cycle(tmp_path, capsys):
    path = tmp_path / "lc.json"
    assert main(["tune", "limit-cycle", "--predict-only", "--json", str(path)]) == 0
    assert json.loads(path.read_text())["predicted"]["amplitude_deg"] > 0.5  # the paper's ±¾° cycle
    assert main(["tune", "limit-cycle", "--predict-only", "--velocity-filter-hz", "5", "--json", str(path)]) == 0
    assert json.loads(path.read_text())["predicted"]["amplitude_deg"] is None


def test_a_negative_cutoff_is_an_argument_error(capsys):
    with pytest.raises(SystemExit) as e:
        main(["tune", "bode", "--velocity-filter-hz", "-1"])
    assert e.value.code == 2 and "--velocity-filter-hz" in capsys.readouterr().err
