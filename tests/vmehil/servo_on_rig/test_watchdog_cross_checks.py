"""The watchdog's cross-checks (servo.watchdog): they catch single sensor and actuator faults fast
and leave the modelled physics alone — the tach's dead band, the paper's limit cycle, the
uncalibrated pots' bow, start-up, calibration applied at run time."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from hal.config import ConfigError
from servo.io import PotCalibration
from servo.runner import LockstepRunner
from servo.watchdog import CrossChecks, WatchdogConfig
from vmehil.cli import main
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

T = 0.008


@pytest.mark.slow
@pytest.mark.parametrize("argv", [["--no-integrator-switch-off"], [], ["--rig", "melmalec-16"]],
                         ids=["paper-limit-cycle", "default", "melmalec-16"])
def test_the_demo_runs_to_the_end_without_a_stop(tmp_path: Path, argv: list[str]) -> None:
    out = tmp_path / "run.json"
    assert main(["run", "--quiet", "--json", str(out), *argv]) == 0
    data = json.loads(out.read_text())
    assert data["faults"] == [] and data["ticks"] == 1844
    if argv == ["--no-integrator-switch-off"]:  # the ±0.74° cycle whose peak speed is the tach's dead band
        assert 0.6 <= data["joints"][0]["limit_cycle"]["amplitude_deg"] <= 0.9


def _loop(rig=None, **wd):
    system = build_emulated_rig(rig, seed=0)
    loop = build_loop(system, n_ticks=400)
    for k, v in wd.items():
        setattr(loop.watchdog, k, v)
    loop.start()
    return system, loop, LockstepRunner(system, loop)


class _FakeIO:
    """Drivers of one joint with a pot, an encoder and a tach (dead band 0.12 rad/s)."""

    n, period_s = 1, T
    calibration_generation = 0
    last_current_a = np.zeros(1)

    def resolution(self):
        one = np.ones(1)
        return SimpleNamespace(pot_rad=1.45e-3 * one, encoder_rad=3.1e-5 * one, tach_rad_s=4.9e-3 * one,
                               monitor_a=np.full(1, np.nan), command_a=np.full(1, np.nan), current_limit_a=one,
                               linear=np.ones(1, bool))


def _feed(checks: CrossChecks, speed_rad_s: float, tach_rad_s: float, ticks: int = 40):
    """A joint moving at ``speed`` while its tach reads ``tach``; the first trip, if any."""
    for k in range(ticks):
        theta = np.array([speed_rad_s * k * T])
        m = SimpleNamespace(theta_pot=theta, theta_enc=theta, omega_tach=np.array([tach_rad_s]),
                            current=np.full(1, np.nan))
        trip = checks.check(m, theta, np.array([speed_rad_s]))
        if trip is not None:
            return trip
    return None


def _checks() -> CrossChecks:
    return CrossChecks(_FakeIO(), WatchdogConfig(following_error_rad=np.ones(1), tach_dead_band_rad_s=np.full(1, 0.12)))


def test_a_tach_reading_zero_inside_its_dead_band_is_healthy_and_outside_it_is_not() -> None:
    assert _feed(_checks(), 0.11, 0.0) is None  # blind by design below 0.12 rad/s
    assert _feed(_checks(), 0.30, 0.30 - 0.12) is None  # a healthy tach reads ω less the brush drop
    trip = _feed(_checks(), 0.30, 0.0)  # stuck at 0 V while the joint moves well above the dead band
    assert trip is not None and trip.cause == "velocity_mismatch" and "dead band included" in trip.detail
    assert _feed(_checks(), 0.0, 10.0).cause == "velocity_mismatch"  # at the rail


def test_a_one_tick_current_glitch_is_tolerated_three_ticks_stop() -> None:
    system, loop, runner = _loop()
    runner.run(100)
    dac = system.crate.board("dac0")
    dac.inject("dead_channel", channel=0)
    runner.run(1)
    dac.clear_fault("dead_channel")
    runner.run(20)
    assert loop.fault is None
    assert loop.cross_checks.peak_ratio["current"][0] > 1.0  # the glitch did exceed the limit, once
    k = loop.tick_count
    dac.inject("dead_channel", channel=0)  # the next exchange gets 0 V; tick k+1 reads the first 0 A
    runner.run(5)
    assert loop.fault is not None and loop.fault.cause == "current_mismatch" and loop.fault.joint == "j1"
    assert loop.fault.tick == k + 3  # the third mismatching sample in a row


def test_a_calibration_applied_while_servoing_re_references_the_encoder_pot_check() -> None:
    system, loop, runner = _loop()
    runner.run(100)
    # a table that reads 1° more than the nominal scaling everywhere: without re-referencing the
    # encoder/pot check would see a 1° jump of the pot alone (its limit is 0.7°)
    v = np.linspace(-10.0, 10.0, 9)
    s = system.io.scaling[0]
    angles = (v - s.pot_zero_v) / s.pot_v_per_rad + np.radians(1.0)
    loop.submit(lambda lp: (lp.io.set_pot_calibration(0, PotCalibration(list(v), list(angles))),
                            lp.set_motion(lp.sequencer.__class__([], lp.io.read().theta, lp.plan_context))))
    runner.run(100)
    assert loop.fault is None
    assert loop.cross_checks.peak_ratio["position"][0] < 1.0


def test_healthy_runs_stay_well_inside_the_position_and_current_limits() -> None:
    _, loop, runner = _loop()
    runner.run(400)  # the demo move's first 3.2 s, through its fastest part
    assert loop.fault is None
    peak = loop.cross_checks.peak_ratio
    assert peak["position"][:6].max() < 0.7 and peak["current"][:6].max() < 0.7
    assert 0.5 < peak["velocity"][0] < 1.0  # j1 runs through its tach's dead band: close, by design


def test_stale_detection_while_moving_catches_a_frozen_pot_on_its_own() -> None:
    system, loop, runner = _loop(cross_checks=False)  # no encoder to compare with: the stale rule alone
    runner.run(100)
    system.plant.inject("pot_frozen", joint="j1")
    runner.run(60)
    assert loop.fault is not None and loop.fault.cause == "stale_sensor" and loop.fault.joint == "j1"
    assert loop.fault.tick - 100 <= 50


def test_the_rig_file_sets_the_limits_per_joint_and_refuses_unknown_keys(tmp_path: Path) -> None:
    from emulators.presets import resolve_rig
    from servo.rig import load_rig

    text = Path(resolve_rig("jpl-arm")).read_text()
    text = text.replace("following_error_limit_deg = 15.0",
                        "following_error_limit_deg = 15.0\nwatchdog = { current_mismatch_ticks = 5, "
                        "position_tolerance_deg = 2.0 }", 1)
    text = text.replace('velocity = "tach"', 'velocity = "tach"\nwatchdog = { tach_dead_band_deg_s = 3.0 }', 1)
    rig = tmp_path / "rig.toml"
    rig.write_text(text)
    system = build_emulated_rig(load_rig(rig), seed=0)
    wd = build_loop(system).watchdog
    assert wd.current_mismatch_ticks == 5
    np.testing.assert_allclose(wd.position_tolerance_rad, np.radians(2.0))
    assert wd.tach_dead_band_rad_s[0] == pytest.approx(np.radians(3.0))
    assert wd.tach_dead_band_rad_s[1] == pytest.approx(0.12 / 0.75)  # j2: its [joint.tach] datasheet value
    rig.write_text(text.replace("position_tolerance_deg = 2.0", "position_tolerence_deg = 2.0"))
    with pytest.raises(ConfigError, match=r"servo\.watchdog\.position_tolerence_deg"):
        build_loop(build_emulated_rig(load_rig(rig), seed=0))


def _current_trip(lag_ticks: int, answer_lag: int):
    """A current monitor that answers the command ``answer_lag`` ticks late, through a ramp of
    commands; the first trip of a current check that allows ``lag_ticks`` of lag."""
    io = _FakeIO()
    res = io.resolution()
    res.monitor_a, res.command_a = np.full(1, 0.003), np.full(1, 0.0006)
    io.resolution = lambda: res
    io.last_current_a = np.zeros(1)
    checks = CrossChecks(io, WatchdogConfig(following_error_rad=np.ones(1), command_lag_ticks=lag_ticks))
    commands = [0.0] * 3 + [0.5 * k for k in range(1, 20)]  # amperes: a move starts
    for k in range(3, len(commands)):
        io.last_current_a = np.array([commands[k - 1]])  # the command the plant was sent last tick
        m = SimpleNamespace(theta_pot=np.zeros(1), theta_enc=np.zeros(1), omega_tach=np.zeros(1),
                            current=np.array([commands[k - 1 - answer_lag]]))
        trip = checks.check(m, np.zeros(1), np.zeros(1))
        if trip is not None:
            return trip
    return None


def test_the_current_check_allows_for_a_free_running_plants_late_answers_and_only_for_those() -> None:
    assert _current_trip(0, 0) is None  # lockstep: the monitor reads last tick's command
    trip = _current_trip(0, 2)  # answers two periods late, judged with lockstep timing: a false trip
    assert trip is not None and trip.cause == "current_mismatch"
    assert _current_trip(2, 2) is None  # free-running: the lag is allowed for
    assert _current_trip(2, 4) is not None  # but not more than it


def _free_running_feed(checks: CrossChecks, steps: list[int], speed_rad_s: float, *, timed: bool):
    """A joint moving at ``speed`` (tach reading it exactly), sampled by a loop whose tick ``k``
    holds the plant's step ``steps[k]`` (a free-running plant: steps skipped and repeated);
    ``timed``: the loop is told each sample's plant time. The first trip, if any."""
    for step in steps:
        theta = np.array([speed_rad_s * step * T])
        m = SimpleNamespace(theta_pot=theta, theta_enc=theta, omega_tach=np.array([speed_rad_s]),
                            current=np.full(1, np.nan))
        trip = checks.check(m, theta, np.array([speed_rad_s]), step * T if timed else None)
        if trip is not None:
            return trip
    return None


def test_the_velocity_check_integrates_over_the_plant_time_of_free_running_samples() -> None:
    """A loop on a free-running plant gets some steps twice and misses others (a late tick reads
    two steps at once): told each sample's plant time, the tach/encoder comparison holds for a
    healthy joint at speed; counted as one period per tick, the same samples trip it."""
    rng = np.random.default_rng(4)
    steps = np.cumsum(rng.choice([0, 1, 1, 1, 2, 3], size=120)).tolist()  # 0: a repeat, 2-3: steps missed
    assert _free_running_feed(_checks(), steps, 0.5, timed=True) is None
    trip = _free_running_feed(_checks(), steps, 0.5, timed=False)
    assert trip is not None and trip.cause == "velocity_mismatch"
    # and told the time, a stuck tach is still caught (0 V at 0.5 rad/s, well above the dead band)
    checks = _checks()
    for step in steps:
        theta = np.array([0.5 * step * T])
        m = SimpleNamespace(theta_pot=theta, theta_enc=theta, omega_tach=np.zeros(1), current=np.full(1, np.nan))
        if (trip := checks.check(m, theta, np.array([0.5]), step * T)) is not None:
            break
    assert trip is not None and trip.cause == "velocity_mismatch"


def test_a_homed_encoder_is_compared_with_the_pot_absolutely() -> None:
    # the pot reads 30°; the encoder 2° more, standing still. Unhomed, the encoder's reading is
    # relative (power-up zero): no travel, no disagreement. Homed, it is the joint's angle: 2° off
    # the pot is a mismatch (limit 8 pot codes + 2 counts ≈ 0.67°).
    def first_trip(homed: bool):
        io = _FakeIO()
        io.homed = np.array([homed])
        checks = CrossChecks(io, WatchdogConfig(following_error_rad=np.ones(1), cross_checks=True))
        pot, enc = np.radians([30.0]), np.radians([32.0])
        m = SimpleNamespace(theta_pot=pot, theta_enc=enc, omega_tach=np.zeros(1), current=np.full(1, np.nan))
        for _ in range(3):
            trip = checks.check(m, pot, np.zeros(1))
            if trip is not None:
                return trip
        return None

    assert first_trip(False) is None
    trip = first_trip(True)
    assert trip is not None and trip.cause == "position_mismatch" and "disagree by 2.00°" in trip.detail
