"""`vmehil run --units parallel|single` (docs/melmalec.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from vmehil.cli import main
from vmehil.reports import run_report


def run_json(tmp_path, *argv: str) -> tuple[int, dict]:
    out = tmp_path / f"{len(list(tmp_path.iterdir()))}.json"
    status = main(["run", "--rig", "melmalec-16", "--quiet", "--duration", "0.5", "--seed", "6",
                   "--json", str(out), *argv])
    return status, json.loads(out.read_text())


def test_run_units_parallel_reports_every_unit_with_the_single_runs_figures(tmp_path, monkeypatch, capsys) -> None:
    """--json: the single run's summary, of every joint (the units' loops merged in joint order:
    the same numbers), plus each unit's; the table ends with a line per unit."""
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "no-calibration"))  # nominal in both runs
    status, single = run_json(tmp_path)
    assert status == 0
    capsys.readouterr()
    status, par = run_json(tmp_path, "--units", "parallel")
    assert status == 0
    assert par["joints"] == single["joints"] and par["motion_end_s"] == single["motion_end_s"]
    assert par["ticks"] == single["ticks"] == par["ticks_planned"] == 62
    out = capsys.readouterr().out
    # the run's 62 ticks and the power-up, then each unit's end: its category-1 stop and 2 s watched
    steps = par["plant_steps"]
    assert steps >= 63 + 250 and f"units (parallel; plant steps {steps}):" in out
    assert "  arm    4 joints  ticks 62  ran to the end  stop verified" in out
    assert par["units_mode"] == "parallel" and par["stop"] is None
    # the single run's end, with the single run's keys (issue #29): category 1, every joint's excursion
    stop, ref = par["final_stop"], single["final_stop"]
    assert set(ref) <= set(stop)
    assert stop["category"] == ref["category"] == 1 and stop["cause"] == "end" and stop["fell_to_0"] is None
    for key in ("excursion_deg", "excursion_sensor_deg"):
        assert list(stop[key]) == list(ref[key]) == [j["name"] for j in single["joints"]]
    assert "final stop: end (category 1); moved after the stop" in out
    assert list(par["units"]) == ["leg1", "leg2", "leg3", "leg4", "arm"]
    joints = {j["name"]: j for u in par["units"].values() for j in u["joints"]}
    assert len(joints) == 16
    for j in single["joints"]:  # each unit's own summary: the same numbers, joint by joint
        assert joints[j["name"]]["final_error_deg"] == j["final_error_deg"]
        assert joints[j["name"]]["max_tracking_error_deg"] == j["max_tracking_error_deg"]


@pytest.mark.slow  # report figures: 32 four-panel matplotlib figures (~4 s each run, more under load)
def test_run_units_parallel_writes_the_single_runs_report(tmp_path, monkeypatch) -> None:
    """--report: the single run's report (summary.md, run.json, one plot per joint) from the units'
    loops merged in joint order -- every plot draws the same curves -- plus the units section."""
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "no-calibration"))
    drawn: dict[str, list] = {}

    def save_figure(fig, path, *a, **kw):  # what each plot draws, not its pixels (rendering 32 PNGs: ~40 s)
        drawn[str(path)] = [np.asarray(line.get_ydata(), float) for ax in fig.axes for line in ax.lines]
        return []

    monkeypatch.setattr(run_report, "save_figure", save_figure)
    for mode in ("single", "parallel"):
        assert run_json(tmp_path, "--units", mode, "--report", str(tmp_path / mode))[0] == 0
    report = {d: json.loads((tmp_path / d / "run.json").read_text()) for d in ("single", "parallel")}
    assert report["parallel"]["joints"] == report["single"]["joints"]
    plots = sorted(Path(p).name for p in drawn if Path(p).parent.name == "single")
    assert len(plots) == 16 and plots == sorted(Path(p).name for p in drawn if Path(p).parent.name == "parallel")
    for name in plots:  # every joint's plot draws the same curves (by hand: the PNGs are byte-identical)
        a, b = drawn[str(tmp_path / "single" / name)], drawn[str(tmp_path / "parallel" / name)]
        assert len(a) == len(b) > 5, name
        assert all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a, b, strict=True)), name
    md = (tmp_path / "parallel" / "summary.md").read_text()
    assert f"units (parallel; plant steps {report['parallel']['plant_steps']}):" in md
    assert "  leg2   3 joints  ticks 62  ran to the end" in md


def test_run_units_parallel_refuses_a_rig_without_units_and_options_it_does_not_take(capsys) -> None:
    assert main(["run", "--rig", "jpl-arm", "--units", "parallel", "--quiet", "--duration", "0.1"]) == 2
    assert "declares no [[rig.unit]] tables" in capsys.readouterr().err
    assert main(["run", "--rig", "melmalec-16", "--units", "parallel", "--quiet", "--duration", "0.1",
                 "--console", "tcp:127.0.0.1:0"]) == 2
    assert "--console: the operator console drives one servo loop" in capsys.readouterr().err
