"""`vmehil run --units parallel` with the single run's options (docs/melmalec.md, "Options with
--units parallel"): the calibration, fault injection routed to the unit that owns the board, the
refusals; and a dead unit's amplifiers latched off by the CAN plant node's command timeout."""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from emulators.presets import resolve_rig
from servo.joint_groups import rig_units
from servo.motion import hold_motion
from servo.rig import load_rig
from servo.runner import LockstepRunner
from tests.vmehil.test_units_parallel import BoardProbe, chain, hub_captured
from vmehil.calibration.store import CalibrationStore, JointCal, load_store, utc_now
from vmehil.cli import main
from vmehil.fault_scenarios.injection import parse_fault_spec
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig
from vmehil.unit_controllers import coordinator
from vmehil.unit_controllers.coordinator import run_units
from vmehil.unit_controllers.options import UnitFaultError, route_faults

RIG = load_rig(resolve_rig("melmalec-16"))


# --- calibration -------------------------------------------------------------------------------
def _calibration_file(path) -> str:
    """A pot table for leg2_lift shifted by 0.05 rad and a 3 mV offset on every channel of adc4
    (the arm's ADC): readings that differ from nominal on those joints only."""
    from vmehil.calibration.store import BoardCal, rig_boards

    s = CalibrationStore.empty(RIG)
    s.set_joint("leg2_lift", JointCal("pot", 1, utc_now(), {"volts": [-9.0, 0.0, 9.0],
                                                             "angles_rad": [-2.65, 0.05, 2.75]}))
    from hal.adc_dac.adc_regs import ADC_CHANNELS
    from hal.adc_dac.calibration import Calibration

    s.set_board(BoardCal(rig_boards(RIG)["adc4"], Calibration((0.003,) * ADC_CHANNELS, (1.0,) * ADC_CHANNELS),
                         "adc", 1, utc_now(), ()))
    return str(s.save(path / "melmalec-16.toml"))


def _single(n_ticks: int, calibration) -> dict[str, np.ndarray]:
    system = build_emulated_rig(RIG, seed=2, calibration=calibration)
    loop = build_loop(system, motion=hold_motion(), n_ticks=n_ticks)
    with loop.armed():
        LockstepRunner(system, loop).run(n_ticks)
    system.close()
    return loop.recorder.trimmed()


def test_a_calibration_file_changes_the_same_joints_readings_in_the_units_as_in_the_single_run(tmp_path) -> None:
    n = 20
    path = _calibration_file(tmp_path)
    nominal, single = _single(n, None), _single(n, path)
    run = run_units(RIG, seed=2, n_ticks=n, motion=hold_motion(), calibration=load_store(path, RIG))
    try:
        par = run.recorded()
    finally:
        run.close()
    for key in ("theta_pot", "theta", "current", "theta_true"):
        assert np.array_equal(single[key], par[key], equal_nan=True), key  # bit for bit, with the file
    changed = [RIG.joints[i].name for i in range(RIG.n_joints)
               if not np.array_equal(nominal["theta_pot"][:, i], par["theta_pot"][:, i], equal_nan=True)]
    assert changed == ["leg2_lift", "arm_base", "arm_shoulder", "arm_elbow"]  # the pot table; adc4's pots
    assert abs(np.degrees(par["theta_pot"][0, 4] - nominal["theta_pot"][0, 4])) > 1.0  # the table, not noise


def test_run_units_parallel_takes_the_calibration_file_and_refuses_a_missing_one(tmp_path, capsys) -> None:
    path = _calibration_file(tmp_path)
    args = ["run", "--rig", "melmalec-16", "--quiet", "--duration", "0.1", "--motion", "none", "--seed", "2"]
    out = {}
    for mode in ("single", "parallel"):
        assert main([*args, "--units", mode, "--calibration", path, "--json", str(tmp_path / f"{mode}.json")]) == 0
        assert f"calibration: {path}" in capsys.readouterr().err
        out[mode] = json.loads((tmp_path / f"{mode}.json").read_text())
    assert out["single"]["joints"] == out["parallel"]["joints"]
    assert main([*args, "--units", "parallel", "--calibration", str(tmp_path / "nope.toml")]) == 2
    assert "--calibration" in capsys.readouterr().err


# --- faults ------------------------------------------------------------------------------------
def test_a_fault_on_one_units_board_stops_every_unit_read_on_their_boards(tmp_path, monkeypatch, capsys) -> None:
    """amp_fault_line on leg3_knee (pio2, leg3's PIO) at 0.4 s: leg3 stops in tick 50, every other
    unit in the same tick; every unit's boards read off (enables low, DACs 0 V, PWM off); the JSON
    says the stop as the single run does."""
    probe = BoardProbe()
    runs: list = []
    original = coordinator.run_units

    def spy(*a, **kw):
        run = original(*a, after_tick=chain(probe), **kw)
        runs.append(run)
        return run

    monkeypatch.setattr(coordinator, "run_units", spy)
    monkeypatch.setenv("VMEHIL_CALIBRATION_DIR", str(tmp_path / "none"))
    out = tmp_path / "par.json"
    status = main(["run", "--rig", "melmalec-16", "--units", "parallel", "--quiet", "--duration", "0.6", "--seed", "6",
                   "--fault", "amp_fault_line@0.4:joint=leg3_knee", "--json", str(out)])
    assert status == 1
    assert "fault: amp_fault_line at 0.4 s (tick 50) → pio2:PB2" in capsys.readouterr().out
    (run,) = runs
    for u in run.units:
        assert probe.off[u.unit.name][49] is False  # on and moving before the fault
        assert probe.first_off(u.unit.name) == 50, u.unit.name
        assert u.loop.final_stop["verified"], u.unit.name
    assert all(x == 0 for x in run.hub.amps_on[52:])  # the plant: every amplifier off
    summary = json.loads(out.read_text())
    assert summary["injected_faults"][0]["unit"] == "leg3" and summary["injected_faults"][0]["target"] == "pio2:PB2"
    stop = summary["stop"]
    assert (stop["cause"], stop["tick"], stop["joint"], stop["ticks_after_fault"], stop["unit"]) == (
        "amplifier_fault", 50, "leg3_knee", 0, "leg3")
    assert [u["faults"][0]["cause"] for u in summary["units"].values()] == ["unit_stop"] * 2 + [
        "amplifier_fault"] + ["unit_stop"] * 2


def _rig_with_a_spare_board(tmp_path):
    text = resolve_rig("melmalec-16").read_text()
    text += '\n[[crate.board]]\ntype = "adc"\nname = "adc9"\nslot = 1\nspace = "A16"\nbase = 0x7F00\n'
    path = tmp_path / "melmalec-spare.toml"
    path.write_text(text)
    return path


def test_a_fault_goes_to_the_unit_owning_its_joint_or_board_and_an_unowned_board_is_refused(tmp_path,
                                                                                            capsys) -> None:
    faults = [parse_fault_spec(t) for t in ("pot_frozen@0.2:joint=arm_elbow", "board_removed@0.3:board=quad2",
                                            "adc_noise:board=adc0", "enable_stuck_low:joint=crawler")]
    routed = route_faults(faults, RIG, rig_units(RIG))
    assert {u: [f.kind.name for f in fs] for u, fs in routed.items()} == {
        "leg1": ["adc_noise"], "leg2": [], "leg3": ["board_removed"], "leg4": [], "arm": ["pot_frozen",
                                                                                          "enable_stuck_low"]}
    with pytest.raises(UnitFaultError, match="can_frame_loss .* not a fault of one unit's joints or boards"):
        route_faults([parse_fault_spec("can_frame_loss:percent=5")], RIG, rig_units(RIG))
    spare = _rig_with_a_spare_board(tmp_path)
    status = main(["run", "--rig", str(spare), "--units", "parallel", "--quiet", "--duration", "0.1",
                   "--fault", "board_removed@0.05:board=adc9"])
    assert status == 2
    err = capsys.readouterr().err
    assert "board 'adc9' belongs to no unit" in err and "the units' boards are leg1: " in err


def test_a_plant_fault_reaches_the_one_plant_at_the_single_runs_tick() -> None:
    """pot_frozen on arm_elbow (the plant's) at tick 30, routed to the arm: the same readings as the
    single run, bit for bit."""
    from vmehil.fault_scenarios.injection import FaultContext, FaultSchedule
    from vmehil.unit_controllers.coordinator import plant_link_for
    from vmehil.unit_controllers.options import fault_hook

    n = 60
    text = "pot_frozen@0.24:joint=arm_elbow"

    def single(faults):
        system = build_emulated_rig(RIG, seed=5)
        loop = build_loop(system, n_ticks=n)
        runner = LockstepRunner(system, loop)
        with loop.armed():
            FaultSchedule(faults, FaultContext(system, loop, 5)).attach(runner)
            runner.run(n)
        return loop.recorder.trimmed()

    ref, clean = single([parse_fault_spec(text)]), single([])
    link = plant_link_for(RIG, 5)
    hook, schedules = fault_hook(route_faults([parse_fault_spec(text)], RIG, rig_units(RIG)), link, 5)
    run = run_units(RIG, seed=5, n_ticks=n, link=link, before_run=hook)
    try:
        assert list(schedules) == ["arm"] and schedules["arm"].faults[0].tick == 30
        got = run.recorded()
        assert link.plant.active_faults  # the one plant of every joint has it
        pot, clean_pot = got["theta_pot"][:, 14], clean["theta_pot"][:, 14]  # the fault shows from tick 31
        assert np.array_equal(pot[:31], clean_pot[:31]) and not np.array_equal(pot[31:], clean_pot[31:])
        for key in ref:
            if key != "compute_s":
                assert np.array_equal(ref[key], got[key], equal_nan=True), key
    finally:
        run.close()


def test_options_that_need_one_loop_are_refused_with_why_and_what_to_do(capsys) -> None:
    argv = ["run", "--rig", "melmalec-16", "--units", "parallel", "--quiet", "--duration", "0.1"]
    assert main([*argv, "--mavlink", "udpin:127.0.0.1:14550"]) == 2
    err = capsys.readouterr().err
    assert "--mavlink: live tuning talks to one servo loop" in err and "--units single --mavlink" in err
    assert main([*argv, "--bus", "vme_user"]) == 2
    assert "--bus: the unit controllers run on emulated boards" in capsys.readouterr().err


# --- a dead unit and the plant node's amplifier-side command timeout --------------------------------
@pytest.mark.slow
def test_a_hung_unit_has_its_amplifiers_latched_off_by_the_plant_nodes_command_timeout() -> None:
    """The plant of every joint as the CAN plant node (virtual bus, a node thread with the command
    timeout `vmehil plant-node` has, 0.2 s). leg2 (not leg1, whose PIO carries the enable-watchdog
    line) hangs after tick 50: no unit's commands for exchange 52 reach the node (the hub waits for
    leg2), so the node's command timeout latches every enabled amplifier off -- leg2's among them --
    before the coordinator's own lost-unit timeout (3 s) runs out; the plant reads every amplifier
    off and latched by `command_timeout` while the hub has still made only exchange 51. Then the
    hub declares leg2 lost and every other unit safe-stops in tick 51 (its boards read off)."""
    from emulators.plant.amplifier import WATCHDOG_COMMAND_TIMEOUT
    from vmehil.option_groups.can_options import CanPlantOptions

    link = CanPlantOptions(interface="virtual", channel="units-cmd-timeout", own_node=True).open_link(RIG, 1)
    node = link.node.node
    # The timeout is armed only when leg2 hangs: armed from the start, a wall-clock pause of the
    # lockstep threads on a loaded machine (0.3 s seen in CI) tripped it before the hang.
    node.command_timeout_s = None  # off (as `vmehil plant-node --command-timeout 0`)
    leg2 = list(rig_units(RIG)[1].indices)
    seen: dict = {}
    holder: dict = {}
    probe = BoardProbe()

    def hang(name, system, loop):
        if name == "leg2" and loop.tick_count == 51:
            seen["before"] = node.amplifiers()  # amplifiers on, nothing latched, just before the silence
            node.command_timeout_s = 0.2  # as `vmehil plant-node` (default 0.2 s); the node thread reads it live
            deadline = time.monotonic() + 60.0
            while not node.command_timed_out and time.monotonic() < deadline:  # wait for the condition
                time.sleep(0.005)
            seen["exchanges"] = holder["hub"].exchanges
            seen["latched"] = node.amplifiers()
            seen["plant_enabled"] = node.plant.amplifier_enabled().copy()
            seen["silence_s"] = node.last_silence_s
            assert holder["hub"].lost.wait(timeout=60.0)

    with hub_captured(holder):
        run = run_units(RIG, seed=1, n_ticks=90, link=link, timeout_s=3.0, after_tick=chain(probe, hang))
    try:
        assert seen["before"].enabled.all() and not seen["before"].tripped.any()
        assert node.counters.command_timeouts >= 1 and seen["silence_s"] >= 0.2
        assert seen["exchanges"] == 52  # power-up + ticks 0..50: the node latched before exchange 52
        latched = seen["latched"]
        assert not seen["plant_enabled"].any() and not latched.enabled.any()  # read from the plant
        assert (latched.cause[leg2] == WATCHDOG_COMMAND_TIMEOUT).all()  # the hung unit's, and every other's
        assert (latched.cause == WATCHDOG_COMMAND_TIMEOUT).all()
        # latched: still off after the commands came again (the others' enables never rose again)
        assert not node.amplifiers().enabled.any() and not node.plant.amplifier_enabled().any()
        for u in run.units:
            assert probe.off[u.unit.name][50] is False
            assert probe.first_off(u.unit.name) == 51, u.unit.name
            assert u.loop.fault.cause == "unit_lost" and u.loop.final_stop["verified"], u.unit.name
        assert run.hub.stop.unit == "leg2" and run.hub.stop.what.startswith("lost")
    finally:
        run.close()
