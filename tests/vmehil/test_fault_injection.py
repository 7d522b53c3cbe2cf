"""`vmehil run --fault` / `--faults` / `--fault list`: parsing, the scenario file, the mapping to the
emulators' named faults through the rig's wiring, and what the summary says."""

from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

from hal.config import ConfigError
from vmehil.cli import main
from vmehil.fault_matrix import MATRIX, run_case
from vmehil.fault_scenarios.injection import CATALOGUE, FaultSpecError, load_scenario, parse_fault_spec


def test_fault_list_prints_every_fault_with_its_parameters(capsys) -> None:
    assert main(["run", "--fault", "list"]) == 0
    out = capsys.readouterr().out
    for kind in CATALOGUE.values():
        assert f"{kind.name}  —  " in out
        for p in kind.params:
            assert p.usage() in out


def test_a_spec_gives_name_time_and_parameters_with_defaults() -> None:
    f = parse_fault_spec("encoder_missed@0.25:joint=j2,counts=500")
    assert f.kind.name == "encoder_missed" and f.at_s == 0.25 and f.params == {"joint": "j2", "counts": 500}
    f = parse_fault_spec("pot_frozen:joint=j1")
    assert f.at_s == 0.0 and math.isnan(f.params["volts"])


@pytest.mark.parametrize("spec, key", [
    ("pot_frozn:joint=j1", "name"),
    ("pot_frozen:jiont=j1", "jiont"),
    ("pot_frozen", "joint"),
    ("pot_frozen@soon:joint=j1", "@T"),
    ("pot_frozen@-1:joint=j1", "at_s"),
    ("encoder_missed:joint=j1,counts=1.5", "counts"),
    ("tach_stuck:joint=j1,volts=high", "volts"),
    ("tach_stuck:joint", "parameters"),
])
def test_a_bad_spec_names_what_is_wrong(spec: str, key: str) -> None:
    with pytest.raises(FaultSpecError) as e:
        parse_fault_spec(spec)
    assert e.value.key == key and spec in str(e.value)


def test_a_scenario_file_reads_its_faults_and_its_errors_name_file_and_key(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text('[[fault]]\nname = "dac_dead"\nat_s = 0.5\nparams = { joint = "j3", volts = 1.0 }\n'
                    '[[fault]]\nname = "board_removed"\nparams = { board = "quad1" }\n')
    faults = load_scenario(good)
    assert [(f.kind.name, f.at_s) for f in faults] == [("dac_dead", 0.5), ("board_removed", 0.0)]
    assert faults[0].params == {"joint": "j3", "volts": 1.0}
    for body, key in [('name = "dac_dead"\nparams = { joint = "j3", volt = 1.0 }', "fault[0].params.volt"),
                      ('name = "dac_ded"', "fault[0].name"),
                      ('name = "dac_dead"\nat_s = -1.0\nparams = { joint = "j3" }', "fault[0].at_s"),
                      ('name = "dac_dead"\nparams = { joint = "j3" }\nwhen = 2', "fault[0].when"),
                      ('name = "dac_dead"\nparams = { joint = "j3", volts = "x" }', "fault[0].params.volts")]:
        bad = tmp_path / "bad.toml"
        bad.write_text("[[fault]]\n" + body + "\n")
        with pytest.raises(ConfigError) as e:
            load_scenario(bad)
        assert str(bad) in str(e.value) and f"key '{key}'" in str(e.value)


@pytest.mark.parametrize("argv, message", [
    (["--fault", "can_frame_loss"], "needs the plant over CAN (--plant can)"),
    (["--fault", "vision_death"], "--vision inprocess"),
    (["--fault", "tach_stuck:joint=hand"], "joint hand of rig jpl-arm has no tach wired"),
    (["--fault", "dac_dead:joint=j9"], "no joint 'j9'"),
    (["--fault", "board_removed:board=adc7"], "no board 'adc7'"),
])
def test_run_refuses_a_fault_it_cannot_inject_before_it_starts(capsys, argv, message) -> None:
    assert main(["run", "--duration", "0.1", "--quiet", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_the_summary_lists_the_injected_faults_where_they_struck_and_the_stop(tmp_path: Path) -> None:
    out = tmp_path / "run.json"
    scenario = tmp_path / "s.toml"
    scenario.write_text('[[fault]]\nname = "enable_stuck_high"\nat_s = 0.4\nparams = { joint = "hand" }\n')
    code = main(["run", "--duration", "1.2", "--quiet", "--json", str(out), "--faults", str(scenario),
                 "--fault", "dac_dead@0.8:joint=j1"])
    assert code == 4  # the watchdog stopped the run, and its read-back found the hand's enable still high
    data = json.loads(out.read_text())
    j1, hand = data["injected_faults"]  # --fault first, then the --faults file
    assert (hand["tick"], hand["target"], hand["emulator_fault"]) == (50, "pio0:PC7", "line_stuck")  # the wiring
    assert (j1["tick"], j1["target"], j1["emulator_fault"]) == (100, "dac0:0", "dead_channel")
    stop = data["stop"]
    assert stop["cause"] == "current_mismatch" and stop["joint"] == "j1"
    assert stop["ticks_after_fault"] == stop["tick"] - 50  # counted from the first fault
    assert "safe stop incomplete: hand" in data["faults"][0]["detail"]  # its enable could not be dropped


def test_the_command_line_measures_what_the_matrix_measures(tmp_path: Path) -> None:
    case = next(c for c in MATRIX if c.spec == "pot_frozen:joint=j1")
    out = tmp_path / "run.json"
    main(["run", "--duration", "2.4", "--quiet", "--json", str(out), "--fault", "pot_frozen@0.8:joint=j1"])
    stop, ref = json.loads(out.read_text())["stop"], run_case(case)
    for key in ("cause", "tick", "ticks_after_fault", "true_error_deg", "max_true_error_deg"):
        assert stop[key] == ref[key], key
