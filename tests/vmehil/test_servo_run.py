"""The 125 Hz loop through the full driver stack on the emulated rig (lockstep, seeded)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from servo.motion import default_demo_motion
from servo.runner import LockstepRunner, RealtimeRunner
from vmehil.cli import main
from vmehil.reports.run_report import summarize
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig


def _run(seconds: float, *, seed: int = 0, switch_off: bool | None = None, gains=None, motion=None,
         rig=None, watchdog: bool = True):
    system = build_emulated_rig(rig, seed=seed)
    n_ticks = round(seconds * system.rig.servo_rate_hz)
    loop = build_loop(system, motion=motion, gains=gains, switch_off=switch_off, n_ticks=n_ticks, watchdog=watchdog)
    loop.start()
    runner = LockstepRunner(system, loop)
    runner.run(n_ticks)
    return system, loop, summarize(loop, rig=system.rig.name, seed=seed, realtime=False, overruns=0)


def test_lockstep_is_deterministic_for_a_seed() -> None:
    _, a, _ = _run(1.0, seed=3)
    _, b, _ = _run(1.0, seed=3)
    _, c, _ = _run(1.0, seed=4)
    ra, rb, rc = a.recorder.trimmed(), b.recorder.trimmed(), c.recorder.trimmed()
    np.testing.assert_array_equal(ra["theta"], rb["theta"])
    np.testing.assert_array_equal(ra["theta_true"], rb["theta_true"])
    assert not np.array_equal(ra["theta"], rc["theta"])  # another seed, other noise


def test_realtime_runner_computes_the_same_run_as_lockstep() -> None:
    """Pacing changes timing statistics only: the plant advances one period per tick either way."""
    s1 = build_emulated_rig(None, seed=5)
    l1 = build_loop(s1, n_ticks=50)
    l1.start()
    LockstepRunner(s1, l1).run(50)
    s2 = build_emulated_rig(None, seed=5)
    l2 = build_loop(s2, n_ticks=50)
    l2.start()
    fake = {"t": 0.0}

    def clock() -> float:
        fake["t"] += 1e-4
        return fake["t"]

    rt = RealtimeRunner(s2, l2, clock=clock, sleep=lambda s: fake.__setitem__("t", fake["t"] + s))
    rt.run(50)
    np.testing.assert_array_equal(l1.recorder.trimmed()["theta"], l2.recorder.trimmed()["theta"])
    assert len(rt.timing.compute_s) == 50 and rt.timing.overruns == 0


@pytest.mark.slow
def test_paper_check_limit_cycle_and_switch_off_cure() -> None:
    """JPL paper: with Kv=50, KvI=1000, Kp=100, Kpi=5000 link 1 limit-cycles about ±¾° at 1–3 Hz;
    switching off the integrator inputs (keeping the integrals) and raising Kp removes it."""
    gains = {"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}
    motion = default_demo_motion(7, hold_s=10.0)
    _, loop, s = _run(15.0, gains=gains, switch_off=False, motion=motion)
    j1 = s["joints"][0]
    lc = j1["limit_cycle"]
    assert 0.5 <= lc["amplitude_deg"] <= 1.0, lc
    assert lc["frequency_hz"] is not None and 1.0 <= lc["frequency_hz"] <= 3.0, lc
    pot_lsb_deg = math.degrees(5.934 / 4096)
    assert abs(j1["limit_cycle_pot"]["amplitude_deg"] - lc["amplitude_deg"]) <= 3 * pot_lsb_deg
    assert loop.law.integrating[0]  # never switched off

    system, loop2, s2 = _run(15.0, gains=gains, switch_off=True, motion=motion)
    j1b = s2["joints"][0]
    assert j1b["limit_cycle"]["amplitude_deg"] < 0.1, j1b
    assert not loop2.law.integrating[0]
    # static error bound T_F/(J·Kp_boosted): the frozen loop holds wherever friction sticks it
    p = system.params[0]
    tf_out = p.friction.breakout_nm * (1 + p.friction.ripple_fraction) * p.gear.ratio
    kp_off = float(loop2.law.kp_off()[0])
    bound = math.degrees(tf_out / (p.inertia_at_joint() * kp_off))
    rec = loop2.recorder.trimmed()
    err_true = math.degrees(abs(rec["theta_d"][-1, 0] - rec["theta_true"][-1, 0]))
    err_meas = math.degrees(abs(rec["theta_d"][-1, 0] - rec["theta"][-1, 0]))
    assert err_meas <= bound + 0.1, (err_meas, bound)
    assert err_true <= bound + 1.5  # plus the uncalibrated pot's bow (≈1°)


@pytest.mark.slow
def test_cli_run_writes_json_with_the_public_keys(tmp_path: Path, capsys) -> None:
    out = tmp_path / "run.json"
    rep = tmp_path / "rep"
    assert main(["run", "--duration", "1.0", "--json", str(out), "--report", str(rep), "--quiet"]) == 0
    data = json.loads(out.read_text())
    for key in ("ticks", "overruns", "faults"):
        assert key in data
    assert data["ticks"] == 125
    j = data["joints"][0]
    for key in ("name", "final_error_deg", "max_tracking_error_deg"):
        assert key in j
    assert set(j["limit_cycle"]) >= {"amplitude_deg", "frequency_hz"}
    assert (rep / "summary.md").exists() and list(rep.glob("joint1_*.png"))
    assert "j1" in capsys.readouterr().out


def test_cli_run_rejects_bad_gains_without_traceback(capsys) -> None:
    assert main(["run", "--gains", "kp=-1", "--duration", "0.1"]) == 2
    assert main(["run", "--gains", "kq=1", "--duration", "0.1"]) == 2
    assert main(["run", "--gains", "kp=nan", "--duration", "0.1"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "--gains" in err
