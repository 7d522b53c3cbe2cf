"""`vmehil tune sweep` options of the engines and tolerance studies: --resume after SIGINT,
--vary/--samples/--threshold/--switch-off through the command line, option errors."""

from __future__ import annotations

import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO
from tests.support.dask_cluster import wait_for
from vmehil.cli import main

FAST = ["--move-deg", "2", "--hold", "1"]  # ~1.4 s simulated per point


@pytest.mark.slow
def test_resume_after_sigint_computes_only_the_missing_points(tmp_path: Path, capsys) -> None:
    out = tmp_path / "out"
    # 16 points: the files are written at most once a second, so the second row may be on disk
    # only a second or more after it was computed; the SIGINT must still find points to cut
    args = ["tune", "sweep", "--grid", "kp=80:140:16", "--jobs", "1", "--batch", "1", *FAST, "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", *args, "--out", str(out)], cwd=tmp_path, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    csv_path = out / "sweep.csv"
    try:
        wait_for(lambda: proc.poll() is not None or (csv_path.exists() and len(csv_path.read_text().splitlines()) >= 3),
                 "two points written")
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr
    assert f"--resume {out}" in stderr
    before = json.loads((out / "sweep.json").read_text())
    k = before["completed"]
    assert 2 <= k < 16 and before["interrupted"]

    # another sweep in that folder is refused, naming what differs
    assert main([*args, "--seed", "1", "--resume", str(out)]) == 2
    assert "another sweep" in capsys.readouterr().err

    assert main([*args, "--resume", str(out)]) == 0
    assert f"({k} done before, {16 - k} to go)" in capsys.readouterr().out
    after = json.loads((out / "sweep.json").read_text())
    assert after["finished"] and after["completed"] == 16
    assert [r["index"] for r in after["rows"]] == list(range(16))  # every point once
    kept = {r["index"]: r for r in before["rows"]}
    for r in after["rows"]:
        if r["index"] in kept:
            assert r == kept[r["index"]]  # not computed again (same wall time, to the last bit)
    assert len(list(csv.DictReader(csv_path.open()))) == 16


@pytest.mark.slow
def test_tolerance_study_from_the_command_line_reports_fractions_and_histograms(tmp_path: Path, capsys) -> None:
    out = tmp_path / "mc"
    assert main(["tune", "sweep", "--vary", "coulomb=±20%", "--vary", "tach_brush_drop=normal:10%", "--samples", "2",
                 "--seed", "5", "--switch-off", "both", "--threshold", "lc_amp_deg=0.5", *FAST, "--jobs", "2",
                 "--out", str(out), "--report", str(out), "--quiet"]) == 0
    printed = capsys.readouterr().out
    d = json.loads((out / "sweep.json").read_text())
    rows = d["rows"]
    assert len(rows) == 4 and [r["switch_off"] for r in rows] == [False, False, True, True]
    assert [r["sample"] for r in rows] == [0, 1, 0, 1]
    assert rows[0]["plant_coulomb_nm"] == rows[2]["plant_coulomb_nm"] != rows[1]["plant_coulomb_nm"]
    summary = d["tolerance"]["summary"]
    for mode in ("integrators_on", "switch_off"):
        t = summary[mode]["thresholds"]["lc_amplitude_deg"]
        assert t["limit"] == 0.5 and t["fraction"] == t["over"] / 2
        assert summary[mode]["metrics"]["rms_tracking_error_deg"]["n"] == 2
    assert "over limit-cycle amplitude 0.5 deg" in printed
    assert (out / "tolerance_histograms.png").stat().st_size > 0
    header = (out / "sweep.csv").read_text().splitlines()[0]
    assert header.endswith("plant_coulomb_nm,plant_tach_brush_drop_v")


@pytest.mark.parametrize("extra, words", [
    (["--engine", "local", "--scheduler", "tcp://127.0.0.1:1"], "needs --engine dask"),
    (["--samples", "3"], "--samples needs --vary"),
    (["--threshold", "lc_amp_deg=1"], "give --vary too"),
    (["--vary", "coulomb=lots"], "not a number"),
    (["--vary", "inertia=normal:50%"], "leave the range"),
])
def test_sweep_option_errors_are_clear(extra: list[str], words: str, tmp_path: Path, capsys) -> None:
    assert main(["tune", "sweep", *extra, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    assert words in capsys.readouterr().err


@pytest.mark.slow
def test_ctrl_c_on_the_dask_engine_keeps_the_finished_rows_and_leaves_no_process(tmp_path: Path) -> None:
    """SIGINT to the whole process group (as a terminal's Ctrl-C) during a LocalCluster sweep:
    the running points stop through the sweep's Dask Event, the finished rows are kept, exit 130,
    and every worker process the command started is gone."""
    psutil = pytest.importorskip("psutil")
    pytest.importorskip("distributed")
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # --batch 1: each finished point is a row, so a Ctrl-C after the first finds points to cut (with
    # batches of lanes the 8 points are two batches of 4 that may both end before the signal)
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", "tune", "sweep", "--engine", "dask", "--jobs", "2",
                             "--batch", "1",
                             "--grid", "kp=80:140:8", "--move-deg", "2", "--hold", "3", "--out", str(out), "--quiet"],
                            cwd=tmp_path, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    csv_path = out / "sweep.csv"
    children = []
    try:
        wait_for(lambda: proc.poll() is not None or (csv_path.exists() and len(csv_path.read_text().splitlines()) >= 2),
                 "one point written")
        assert proc.poll() is None, proc.communicate()
        children = psutil.Process(proc.pid).children(recursive=True)
        assert len(children) >= 2  # the LocalCluster's worker processes
        os.killpg(proc.pid, signal.SIGINT)
        _stdout, stderr = proc.communicate(timeout=180)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr, stderr
    _gone, alive = psutil.wait_procs(children, timeout=60)
    assert not alive
    d = json.loads((out / "sweep.json").read_text())
    assert d["interrupted"] and 1 <= d["completed"] < 8
    assert all(r["status"] == "ok" for r in d["rows"])


@pytest.mark.slow
def test_batched_sweep_resumes_after_sigint_and_its_rows_equal_the_scalar_sweep(tmp_path: Path, capsys) -> None:
    """--batch 2: SIGINT ends every instance of the running batch (exit 130, finished rows kept);
    --resume (another batch size) runs only the rest; the rows equal a --batch 1 sweep's, wall_s aside,
    and so do the rows of the 8 points run as one batch of lanes (--batch 8)."""
    out = tmp_path / "out"
    # 8 points in 4 batches: the files are written at most once a second, so the SIGINT must still
    # find batches to cut when the first two rows are on disk
    args = ["tune", "sweep", "--grid", "kp=80:140:8", "--jobs", "1", *FAST, "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, "-m", "vmehil", *args, "--batch", "2", "--out", str(out)], cwd=tmp_path,
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    csv_path = out / "sweep.csv"
    try:
        wait_for(lambda: proc.poll() is not None or (csv_path.exists() and len(csv_path.read_text().splitlines()) >= 3),
                 "the first batch written")
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        _stdout, stderr = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 130, stderr
    before = json.loads((out / "sweep.json").read_text())
    k = before["completed"]
    assert 2 <= k < 8 and k % 2 == 0 and before["interrupted"], stderr  # whole batches only
    assert all(r["status"] == "ok" for r in before["rows"])  # no row of the interrupted batch is kept

    assert main([*args, "--batch", "3", "--resume", str(out)]) == 0
    assert f"({k} done before, {8 - k} to go)" in capsys.readouterr().out
    batched = json.loads((out / "sweep.json").read_text())["rows"]
    assert main([*args, "--batch", "1", "--out", str(tmp_path / "scalar")]) == 0
    scalar = json.loads((tmp_path / "scalar" / "sweep.json").read_text())["rows"]
    strip = lambda rows: [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]  # noqa: E731
    assert strip(batched) == strip(scalar)
    # the 8 points as one batch of lanes (the default's form for 8 or more): the same rows again
    assert main([*args, "--batch", "8", "--out", str(tmp_path / "lanes")]) == 0
    lanes = json.loads((tmp_path / "lanes" / "sweep.json").read_text())["rows"]
    assert strip(lanes) == strip(scalar)


def test_batch_n_refuses_a_rig_with_a_board_type_that_cannot_batch_in_one_line(tmp_path: Path, capsys,
                                                                                monkeypatch) -> None:
    from vmehil.analysis import batch

    # stand-in for a plug-in board type: the decoders' type is not among the batchable ones
    monkeypatch.setattr(batch, "batchable_types", lambda: frozenset({"adc", "dac", "pio", "bit3", "ram"}))
    assert main(["tune", "sweep", "--grid", "kp=80:140:2", *FAST, "--batch", "4", "--out", str(tmp_path / "o"),
                 "--quiet"]) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if "batch" in line]
    assert len(err) == 1 and "--batch 4: rig jpl-arm has board type(s) quad from a plug-in" in err[0]
    assert not (tmp_path / "o").exists()  # refused before anything was written
    assert main(["tune", "sweep", "--batch", "zero", "--out", str(tmp_path / "o")]) == 2
    assert "--batch 'zero': give a number of instances (1 = one run at a time) or auto" in capsys.readouterr().err
