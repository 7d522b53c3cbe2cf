"""`vmehil run --units parallel|single` (docs/melmalec.md)."""

from __future__ import annotations

import json

from vmehil.cli import main


def run_json(tmp_path, *argv: str) -> tuple[int, dict]:
    out = tmp_path / f"{len(list(tmp_path.iterdir()))}.json"
    status = main(["run", "--rig", "melmalec-16", "--quiet", "--duration", "1", "--seed", "6",
                   "--json", str(out), *argv])
    return status, json.loads(out.read_text())


def test_run_units_parallel_reports_every_unit_with_the_single_runs_figures(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "no-calibration"))  # nominal in both runs
    status, single = run_json(tmp_path)
    assert status == 0
    status, par = run_json(tmp_path, "--units", "parallel")
    assert status == 0
    assert par["units_mode"] == "parallel" and par["plant_steps"] == 126 and par["stop"] is None
    assert list(par["units"]) == ["leg1", "leg2", "leg3", "leg4", "arm"]
    joints = {j["name"]: j for u in par["units"].values() for j in u["joints"]}
    assert len(joints) == 16
    for j in single["joints"]:  # the same numbers, joint by joint (lockstep is bit-identical)
        assert joints[j["name"]]["final_error_deg"] == j["final_error_deg"]
        assert joints[j["name"]]["max_tracking_error_deg"] == j["max_tracking_error_deg"]


def test_run_units_parallel_refuses_a_rig_without_units_and_options_it_does_not_take(capsys) -> None:
    assert main(["run", "--rig", "jpl-arm", "--units", "parallel", "--quiet", "--duration", "0.1"]) == 2
    assert "declares no [[rig.unit]] tables" in capsys.readouterr().err
    assert main(["run", "--rig", "melmalec-16", "--units", "parallel", "--quiet", "--duration", "0.1",
                 "--fault", "dac_dead@0.05:joint=leg1_knee"]) == 2
    assert "--fault not supported with parallel units" in capsys.readouterr().err
