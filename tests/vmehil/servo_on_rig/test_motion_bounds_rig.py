"""Motion within bounds on the emulated jpl-arm (issue #32): a move past a soft limit is refused
before any amplifier is enabled, a measured position past a soft limit while running stops the
loop (cause ``soft_limit``, category 1), ``vmehil plan`` reports limits and collisions, and the
console refuses such moves and edits the scene. Stops are read off the emulated boards' nets and
the plant's truth, never a flag of the loop's."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from emulators.presets import resolve_rig
from servo.motion import QuinticMove, hold_motion
from servo.rig import load_rig
from servo.runner import LockstepRunner
from servo.stops import StopCategory
from servo.trajectory import JointLimits, PlanContext, Sequencer
from tests.support.boards import assert_boards_safe, watch_enables
from vmehil.cli import main
from vmehil.rig_setup import system as rig_system
from vmehil.rig_setup.session import build_loop


def test_a_200_deg_target_is_refused_before_any_amplifier_is_enabled(tmp_path, monkeypatch, capsys) -> None:
    motion = tmp_path / "far.toml"
    motion.write_text("[[move]]\ntargets_deg = [200, 0, 0, 0, 0, 0, 30]\n", encoding="utf-8")
    built, raised = watch_enables(monkeypatch)  # every rig the run builds: its enable nets watched from the start
    assert main(["run", "--motion", str(motion), "--quiet", "--scene", "none"]) == 2
    err = capsys.readouterr().err
    assert "joint j1 target 200.00° is past its soft limit max_deg = 163.01°" in err
    assert built and raised == []  # the rig was built (the joints read), no enable line ever rose
    for system in built:
        assert not any(system.crate.signals.get_digital(j.net("amp_enable")) for j in system.rig.joints
                       if "amp_enable" in j.wiring)


def test_a_runtime_overshoot_past_a_soft_limit_stops_the_loop_with_soft_limit(tmp_path) -> None:
    # j1's soft limit at +3°; a target of 10° that no planner checked (as a target known only at run
    # time would be) takes the joint past 3° + 0.5° margin: a category-1 stop from there
    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    path = tmp_path / "rig.toml"
    # (and the watchdog's margin at the default 0.5°, not jpl-arm's 1.75°: the figures below are for it)
    text = text.replace("soft_limit_margin_deg = 1.75", "soft_limit_margin_deg = 0.5", 1)
    path.write_text(text.replace("max_deg = 163.01", "max_deg = 3.0", 1), encoding="utf-8")
    system = rig_system.build_emulated_rig(load_rig(path), seed=0)
    try:
        loop = build_loop(system, motion=hold_motion(), n_ticks=600)
        runner = LockstepRunner(system, loop)
        loop.start()
        runner.run(5)
        start = np.asarray(loop.last["theta_d"], float)
        target = start.copy()
        target[0] = math.radians(10.0)
        unchecked = PlanContext(JointLimits.make(7, math.radians(20.0)))  # no bounds
        loop.set_motion(Sequencer([QuinticMove(target, None)], start, unchecked))
        for _ in range(400):
            runner.tick()
            if not any(system.crate.signals.get_digital(j.net("amp_enable")) for j in system.rig.joints
                       if "amp_enable" in j.wiring):
                break
        runner.tick()  # the exchange that carries the stop to the plant
        assert loop.fault is not None and loop.fault.cause == "soft_limit" and loop.fault.joint == "j1"
        assert loop.stop_category == StopCategory.CONTROLLED and loop.stop_fell is None
        assert "past the soft limit max_deg = +3.00°" in loop.fault.detail
        assert_boards_safe(system)
        truth = system.truth()
        # decelerated from ≈ 3.5° at ≤ 20°/s, 400°/s²: ≤ 0.5° on; far from the 10° target and the stop
        assert 3.0 < math.degrees(truth["theta_joint"][0]) < 5.5
        assert abs(truth["omega_joint"][0]) < math.radians(0.5)
        # enabled again where the stop left it (past the limit): it may come back, not go further
        loop.submit(lambda lp: lp.resume())
        runner.run(30)
        assert loop.fault is None and system.crate.signals.get_digital("j1.amp_enable")
        here = np.asarray(loop.sequencer.current.end, float)
        back = here.copy()
        back[0] = 0.0
        loop.submit(lambda lp: lp.set_motion(Sequencer([QuinticMove(back, None)], here, lp.plan_context)))
        runner.run(150)
        assert loop.fault is None and abs(math.degrees(system.truth()["theta_joint"][0])) < 1.5
    finally:
        system.close()


SCENE = """
[[obstacle]]
name = "box"
min_m = [0.5, -0.1, 0.2]
max_m = [0.7, 0.1, 0.4]
"""
START = "-60,0,0,0,0,0,30"


def test_vmehil_plan_reports_the_collision_at_its_point_and_passes_the_route_around(tmp_path, capsys) -> None:
    scene = tmp_path / "box.scene.toml"
    scene.write_text(SCENE, encoding="utf-8")
    swing = tmp_path / "swing.toml"
    swing.write_text("[[move]]\ntargets_deg = [60, 0, 0, 0, 0, 0, 30]\n", encoding="utf-8")
    out = tmp_path / "plan.json"
    assert main(["plan", str(swing), "--scene", str(scene), f"--start-deg={START}", "--json", str(out)]) == 2
    printed = capsys.readouterr().out
    assert "REFUSED collision: move 1: link upper_arm hits obstacle box at point 10 of 20 (t = 5.329 s" in printed
    report = json.loads(out.read_text(encoding="utf-8"))
    assert report["ok"] is False
    first = report["refusals"][0]
    assert {k: first[k] for k in ("kind", "joint", "link", "obstacle", "point_index")} == {
        "kind": "collision", "joint": None, "link": "upper_arm", "obstacle": "box", "point_index": 9}
    assert first["t_s"] == pytest.approx(11.25 * 9 / 19, abs=1e-6)
    # over it: the shoulder raised 45° on the way (the paper's "safe intermediate points")
    route = tmp_path / "route.toml"
    route.write_text("[[move]]\ntype = \"lspb\"\nvia_deg = [[-60, 45, 0, 0, 0, 0, 30], [60, 45, 0, 0, 0, 0, 30], "
                     "[60, 0, 0, 0, 0, 0, 30]]\n", encoding="utf-8")
    assert main(["plan", str(route), "--scene", str(scene), f"--start-deg={START}", "--json", str(out),
                 "--force"]) == 0
    assert json.loads(out.read_text(encoding="utf-8"))["refusals"] == []
    # a target past a limit: kind "limit", the joint named
    far = tmp_path / "far.toml"
    far.write_text("[[move]]\ntargets_deg = [0, 120, 0, 0, 0, 0, 30]\n", encoding="utf-8")
    assert main(["plan", str(far), "--scene", "none", f"--start-deg={START}", "--json", str(out), "--force"]) == 2
    (limit,) = json.loads(out.read_text(encoding="utf-8"))["refusals"]
    assert (limit["kind"], limit["joint"], limit["link"], limit["obstacle"]) == ("limit", "j2", None, None)


def test_a_parallel_run_with_a_duration_is_refused_past_a_soft_limit_before_any_unit_runs(
        tmp_path, monkeypatch, capsys) -> None:
    """`--units parallel --duration S` plans no probe for the run's length; the motion is checked
    all the same (it once went to the units unchecked, guarded by their watchdogs only)."""
    from vmehil.commands import run_units

    motion = tmp_path / "far.toml"
    targets = [0.0] * 16
    targets[0] = 80.0  # leg1_swing: soft limits ±43.83° (melmalec-16.toml: 2° inside ±0.8 rad)
    motion.write_text(f"[[move]]\ntargets_deg = {targets}\n", encoding="utf-8")
    started: list[object] = []
    monkeypatch.setattr(run_units, "run_parallel", lambda *a, **k: started.append(a) or 0)
    assert main(["run", "--rig", "melmalec-16", "--units", "parallel", "--duration", "2",
                 "--motion", str(motion), "--quiet"]) == 2
    assert "joint leg1_swing target 80.00° is past its soft limit max_deg = 43.83°" in capsys.readouterr().err
    assert started == []


def test_a_short_move_to_a_soft_limit_overshoots_it_without_a_stop(tmp_path) -> None:
    """150° then 162° on j1 (limit 163.01°): the servo overshoots the target by ~1.5° before it
    settles (docs/motion-safety.md, measured); the watchdog's margin on jpl-arm (1.75°) lets an
    accepted move finish — with the default 0.5° it stopped with soft_limit at pot 163.52°."""
    motion = tmp_path / "near.toml"
    motion.write_text("[[move]]\ntargets_deg = [150, 0, 0, 0, 0, 0, 30]\n"
                      "[[move]]\ntargets_deg = [162, 0, 0, 0, 0, 0, 30]\n", encoding="utf-8")
    out = tmp_path / "run.json"
    assert main(["run", "--motion", str(motion), "--scene", "none", "--quiet", "--json", str(out)]) == 0
    import json

    result = json.loads(out.read_text())
    assert result["faults"] == []
    assert result["final_stop"]["cause"] != "soft_limit"


def test_a_rig_that_requires_homing_refuses_a_run_with_moves_and_holds_without(tmp_path, capsys) -> None:
    """`[servo] require_homing = true`: `vmehil run` does not home, so it refuses to move (exit 2,
    nothing enabled) and says where to home; a hold (--motion none) still runs."""
    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    path = tmp_path / "homed.toml"
    path.write_text(text.replace("[servo]\n", "[servo]\nrequire_homing = true\n", 1), encoding="utf-8")
    assert main(["run", "--rig", str(path), "--quiet", "--scene", "none"]) == 2
    assert "requires homing before moves" in capsys.readouterr().err
    assert main(["run", "--rig", str(path), "--quiet", "--scene", "none", "--motion", "none",
                 "--duration", "0.2"]) == 0
