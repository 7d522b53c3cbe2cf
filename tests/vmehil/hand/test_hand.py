"""The hand on the emulated jpl-arm (issue #36): a close at a fixed current stops on contact at the
object's width, both tactile switches close and the hand pot agrees; ``weigh`` finds the object's
mass within its stated uncertainty; the switches and the pot disagreeing is ``ERR GRASP``. Contact
and switches are read off the plant's truth and the PIO board's nets, not a flag of the loop's."""

from __future__ import annotations

import numpy as np
import pytest

from emulators.presets import resolve_rig
from hal.hand import GraspObject
from servo.motion import hold_motion
from servo.rig import load_rig
from servo.runner import LockstepRunner
from servo.scene import Scene
from servo.settings import servo_settings
from vmehil.console.commands import ATOMS, Outcome, Session
from vmehil.console.protocol import ConsoleError
from vmehil.rig_setup.hand_world import attach_hand_world
from vmehil.rig_setup.session import build_loop
from vmehil.rig_setup.system import build_emulated_rig

#: a pose with the tool ahead of the deck, the shoulder and elbow loaded (rad; the hand half open)
POSE_RAD = [0.0, 0.3, -0.6, 0.3, 0.0, 0.0, 0.6]
WIDTH_M, MASS_KG, STIFFNESS_N_PER_M = 0.04, 0.5, 5000.0
HAND = 6
#: jpl-arm's [hand]: 0.1 m of gap per radian; its soft minimum 2° (the fingers "shut")
GAP_M_PER_RAD = 0.1


class Rig:
    def __init__(self, *, object_here: bool = True, seed: int = 0) -> None:
        rig = load_rig(resolve_rig("jpl-arm"))
        settings = servo_settings(rig)
        self.system = build_emulated_rig(rig, seed=seed, initial_deg=list(np.degrees(POSE_RAD)))
        tool = settings.arm.tool_position(self.system.plant.joint_angle())
        where = tool if object_here else tool + np.array([0.0, 0.0, 0.5])  # 0.5 m above: not between the fingers
        self.scene = Scene(source="test", objects=[GraspObject.make("sample", WIDTH_M, MASS_KG, STIFFNESS_N_PER_M,
                                                                    where.tolist())])
        self.loop = build_loop(self.system, motion=hold_motion(), n_ticks=0, settings=settings, scene=self.scene)
        self.world = attach_hand_world(self.system, self.scene, settings)
        self.loop.start()
        self.runner = LockstepRunner(self.system, self.loop)
        self.session = Session(self.loop)
        self.hand = rig.joints[HAND]

    def cmd(self, name: str, **args: object) -> Outcome:
        atom = ATOMS[name]
        return atom.run(self.session, {**{p.name: p.default for p in atom.params}, **args})

    def until(self, out: Outcome, max_ticks: int) -> None:
        assert out.until is not None
        for _ in range(max_ticks):
            self.runner.run(1)
            if out.until(self.loop):
                return
        raise AssertionError(f"not complete in {max_ticks} ticks")

    def switches(self) -> list[bool]:
        sig = self.system.crate.signals
        return [sig.get_digital(self.hand.net(s)) for s in ("tactile_left", "tactile_right")]

    def gap_true_m(self) -> float:
        return GAP_M_PER_RAD * float(self.system.plant.joint_angle()[HAND])

    def close(self) -> None:
        self.system.close()


@pytest.fixture(scope="module")
def grasped():
    """open, rest, close on the object: the state every grasp test reads."""
    r = Rig()
    r.runner.run(25)
    r.until(r.cmd("open"), 800)
    r.until(r.cmd("close"), 800)
    yield r
    r.close()


def test_a_close_stops_on_contact_at_the_objects_width(grasped) -> None:
    # the fingers press 0.5 A · 0.01 N·m/A · 50 / 0.1 m = 2.5 N (less friction) into 5000 N/m: ≤ 0.5 mm in
    assert 0.0395 <= grasped.gap_true_m() <= 0.0401
    assert grasped.loop.fault is None


def test_both_tactile_switches_close_on_contact_and_the_hand_pot_agrees(grasped) -> None:
    assert grasped.switches() == [True, True]  # pio1 PB0, PB1: the nets the board reads
    out = grasped.cmd("grasp", object="sample")
    assert "switches=closed,closed" in out.ok
    gap_mm = float(out.ok.split("gap_mm=")[1].split()[0])
    assert abs(gap_mm - 40.0) <= 6.0  # the rig's grasp_tolerance_m


def test_weigh_finds_the_objects_mass_within_its_stated_uncertainty(grasped) -> None:
    out = grasped.cmd("weigh")
    kv = dict(p.split("=") for p in out.ok.split())
    mass, sigma = float(kv["mass_kg"]), float(kv["uncertainty_kg"])
    assert 0.0 < sigma < 0.2
    assert abs(mass - MASS_KG) <= sigma


def test_the_held_objects_weight_loads_the_arm_through_the_kinematics(grasped) -> None:
    # an independent hand calculation at the grasp pose: the tool point's horizontal distance
    # from each pitch axis times m·g (the weight pulls down: negative torques on j2, j3, j4)
    q2, q3, q4 = grasped.system.plant.joint_angle()[1:4]  # where the arm truly is (it sags a little)
    a2, a3, a5, a6 = 0.60, 0.55, 0.10, 0.15
    r_elbow = a3 * np.cos(q2 + q3) + (a5 + a6) * np.cos(q2 + q3 + q4)
    r_wrist = (a5 + a6) * np.cos(q2 + q3 + q4)
    r_shoulder = a2 * np.cos(q2) + r_elbow
    w = MASS_KG * 9.80665
    ext = grasped.system.plant.external_torque_nm
    np.testing.assert_allclose(ext[1:4], [-w * r_shoulder, -w * r_elbow, -w * r_wrist], rtol=2e-3)


def test_a_stuck_tactile_switch_is_err_grasp(grasped) -> None:
    pio1 = grasped.system.crate.board("pio1")
    pio1.inject("line_stuck", line="PB1", level=False)
    try:
        grasped.runner.run(2)
        with pytest.raises(ConsoleError) as e:
            grasped.cmd("grasp", object="sample")
        assert e.value.code == "GRASP"
        assert "the tactile switches disagree (closed, open)" in e.value.message
    finally:
        pio1.clear_fault("line_stuck")
        grasped.runner.run(2)


def test_a_close_on_nothing_is_err_grasp() -> None:
    r = Rig(object_here=False)
    try:
        r.runner.run(25)
        r.until(r.cmd("close"), 800)
        assert r.switches() == [False, False]
        assert r.gap_true_m() < 0.006  # held at the soft minimum, 2°: 3.5 mm
        assert r.loop.fault is None  # the soft-limit watchdog did not trip
        with pytest.raises(ConsoleError) as e:
            r.cmd("grasp")
        assert e.value.code == "GRASP" and "closed on nothing" in e.value.message
    finally:
        r.close()


def test_a_motion_files_hand_move_closes_the_fingers_on_the_object(tmp_path) -> None:
    from servo.motion import load_motion

    path = tmp_path / "grasp.toml"
    path.write_text('[[move]]\ntype = "hand"\naction = "close"\ncurrent_a = 0.5\nduration_s = 2\n', encoding="utf-8")
    r = Rig()
    try:
        motion = load_motion(path, 7)
        r.runner.run(125)  # the arm settles on its gravity load first (it sags until the integrators take it)
        held = np.asarray(r.loop.sequencer.current.end, float)  # the pots' view of where the arm is held
        r.loop.set_motion(motion.sequencer(held, r.loop.plan_context))
        r.runner.run(250)  # 2 s: 0.2 rad at the fingers' 0.5 rad/s top speed takes 0.4 s
        assert r.switches() == [True, True]
        assert 0.0395 <= r.gap_true_m() <= 0.0401
        assert r.loop.fault is None
    finally:
        r.close()


def test_vmehil_run_closes_the_hand_on_the_scenes_object(tmp_path, monkeypatch) -> None:
    from vmehil.cli import main
    from vmehil.rig_setup import system as rig_system

    scene = tmp_path / "grasp.scene.toml"  # at jpl-arm's tool point at its start pose (all joints 0)
    scene.write_text('[[object]]\nname = "sample"\nwidth_m = 0.04\nmass_kg = 0.5\nstiffness_n_per_m = 5000.0\n'
                     'position_m = [1.4, 0.0, 0.3]\n', encoding="utf-8")
    motion = tmp_path / "grasp.toml"
    motion.write_text('[[move]]\ntype = "wait"\nduration_s = 1\n[[move]]\ntype = "hand"\naction = "close"\n'
                      'duration_s = 2\n', encoding="utf-8")
    built = []
    real_build = rig_system.build_emulated_rig

    def keep(*args, **kwargs):
        s = real_build(*args, **kwargs)
        built.append(s)
        return s

    monkeypatch.setattr(rig_system, "build_emulated_rig", keep)
    assert main(["run", "--motion", str(motion), "--scene", str(scene), "--quiet"]) == 0
    (system,) = [s for s in built if s.grasp is not None]  # the run's rig (a probe rig plans the duration)
    # the fingers stopped at the object's 40 mm (0.4 rad), not at the soft minimum (2°: 3.5 mm)
    assert 0.39 <= float(system.plant.joint_angle()[HAND]) <= 0.401
