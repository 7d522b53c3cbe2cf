"""Motion within bounds (issue #32): the soft limits parsed from the rig file, the planner's check
of every move against them and against the scene (the JPL paper's collision check at twenty
points), and the watchdog's soft-limit test. Expected values are hand calculations (degrees and
the arm's default geometry: links along x at the shoulder's height 0.30 m, 0.60 m then 0.55 m)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from emulators.presets import resolve_rig
from hal.config import ConfigError, ConfigTable
from hal.kinematics import ArmModel
from servo.motion import LspbMove, QuinticMove, WaitMove, parse_motion
from servo.rig import load_rig
from servo.scene import Obstacle, Scene, SceneError, default_scene_path, load_scene, parse_scene
from servo.settings import servo_settings
from servo.trajectory import JointLimits, MotionBounds, MotionRefused, PlanContext, Sequencer
from servo.watchdog import WatchdogConfig

NAMES = ("j1", "j2", "j3", "j4", "j5", "j6", "hand")
D = math.radians


def _deg(*values: float) -> np.ndarray:
    q = np.zeros(7)
    q[: len(values)] = np.radians(values)
    return q


def _bounds(scene: Scene | None = None, lo_deg: float = -160.0, hi_deg: float = 160.0) -> MotionBounds:
    return MotionBounds(NAMES, np.full(7, D(lo_deg)), np.full(7, D(hi_deg)), ArmModel(), scene)


def _ctx(bounds: MotionBounds) -> PlanContext:
    return PlanContext(JointLimits.make(7, D(20.0)), bounds=bounds)  # 20°/s, as the jpl-arm plans


def _rig_with(tmp_path: Path, old: str, new: str) -> Path:
    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    assert old in text
    path = tmp_path / "rig.toml"
    path.write_text(text.replace(old, new, 1), encoding="utf-8")
    return path


# --- the rig file ------------------------------------------------------------------------------------
J1_LIMITS = "min_deg = -163.01"


def test_the_presets_put_the_soft_limits_2_deg_inside_the_hard_stops() -> None:
    for preset in ("jpl-arm", "melmalec-16"):
        data = tomllib.loads(resolve_rig(preset).read_text(encoding="utf-8"))
        templates = data.get("plant", {}).get("templates", {})
        st = servo_settings(load_rig(resolve_rig(preset)))
        for i, jt in enumerate(data["joint"]):
            link = {**templates.get(jt.get("template"), {}).get("link", {}), **jt.get("link", {})}
            lo, hi = math.degrees(link["lower_stop_rad"]), math.degrees(link["upper_stop_rad"])
            if hi - lo > 720:  # the crawler turns on: no soft limits
                assert (st.soft_min_rad[i], st.soft_max_rad[i]) == (-math.inf, math.inf)
                continue
            assert math.degrees(st.soft_min_rad[i]) == pytest.approx(lo + 2.0, abs=0.01), jt["name"]
            # melmalec's knees: 0.2° inside the upper stop, or the default demo (10° from a start the
            # uncalibrated pot reads 0.94° high) would be refused
            inside = 0.2 if jt["name"].endswith("_knee") else 2.0
            assert math.degrees(st.soft_max_rad[i]) == pytest.approx(hi - inside, abs=0.01), jt["name"]


def test_a_soft_limit_at_or_past_a_hard_stop_is_refused_naming_the_key(tmp_path) -> None:
    path = _rig_with(tmp_path, J1_LIMITS, "min_deg = -170.0")  # the stop is −2.88 rad = −165.01°
    with pytest.raises(ConfigError, match=r"joint\[0\]\.limits\.min_deg.*lower_stop_rad"):
        servo_settings(load_rig(path))
    path = _rig_with(tmp_path, "max_deg = 163.01", "max_deg = -170.0")
    with pytest.raises(ConfigError, match="max_deg"):
        servo_settings(load_rig(path))


def test_a_joint_without_limits_has_none_and_the_margin_defaults_to_half_a_degree(tmp_path) -> None:
    path = _rig_with(tmp_path, J1_LIMITS + "  ", "# ")
    # jpl-arm states its own margin (1.75°); without the key the default is 0.5°
    text = path.read_text(encoding="utf-8")
    assert "soft_limit_margin_deg = 1.75" in text
    path.write_text(text.replace("soft_limit_margin_deg = 1.75", "# soft_limit_margin_deg", 1), encoding="utf-8")
    st = servo_settings(load_rig(path))
    assert st.soft_min_rad[0] == -math.inf and math.degrees(st.soft_max_rad[0]) == pytest.approx(163.01)
    assert math.degrees(st.soft_limit_margin_rad) == pytest.approx(0.5)
    assert st.collision_points == 20


# --- the watchdog's test ------------------------------------------------------------------------------
def test_the_watchdog_finds_the_joint_past_a_soft_limit_by_more_than_the_margin() -> None:
    wd = WatchdogConfig(following_error_rad=np.full(3, 1.0), soft_min_rad=np.radians([-10.0, -10.0, -np.inf]),
                        soft_max_rad=np.radians([10.0, 10.0, np.inf]), soft_limit_margin_rad=D(0.5))
    assert wd.beyond_soft_limit(np.radians([10.4, -10.4, 1e6])) is None  # within the margin; no limit
    j, pos, lim, side = wd.beyond_soft_limit(np.radians([10.4, -10.7, 0.0]))
    assert (j, side) == (1, "min") and math.degrees(lim) == pytest.approx(-10.0)
    assert math.degrees(pos) == pytest.approx(-10.7)
    assert wd.beyond_soft_limit(np.radians([10.6, np.nan, 0.0]))[::3] == (0, "max")


# --- limits at plan time ------------------------------------------------------------------------------
def test_a_target_past_a_soft_limit_is_refused_naming_the_joint_the_target_and_the_limit() -> None:
    seq = Sequencer([QuinticMove(_deg(0.0, 170.0), None)], _deg(), _ctx(_bounds()))
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "LIMIT"
    (r,) = err.refusals
    assert (r.kind, r.joint, r.move) == ("limit", "j2", 0)
    assert "j2 target 170.00° is past its soft limit max_deg = 160.00°" in str(err)


def test_an_lspb_via_point_past_a_limit_is_refused_though_its_end_is_inside() -> None:
    move = LspbMove((_deg(-165.0), _deg(0.0)))
    err = Sequencer([WaitMove(1.0), move], _deg(), _ctx(_bounds())).plan_error
    assert isinstance(err, MotionRefused)
    (r,) = err.refusals
    assert (r.joint, r.move, r.point_index) == ("j1", 1, 0)
    assert "move 2: joint j1 target -165.00° is past its soft limit min_deg = -160.00° (point 1 of 2)" in r.detail


def test_a_motion_file_inside_the_limits_plans_as_before() -> None:
    motion = parse_motion(ConfigTable({"move": [{"targets_deg": [30, 20, -40, 10, 0, 5, 20]},
                                                {"type": "wait", "duration_s": 1.0}]}, "m.toml"), 7)
    seq = Sequencer(list(motion.moves), _deg(), _ctx(_bounds()))
    assert seq.plan_error is None and len(seq.planned) == 2


# --- the JPL collision check ----------------------------------------------------------------------------
# A box on the x axis at the shoulder's height: x 0.5..0.7, |y| ≤ 0.1, z 0.2..0.4. The upper arm
# (r 0..0.6 from the waist axis) and the forearm (0.6..1.15) enter it when 0.6·|sin q1| ≤ 0.1,
# |q1| ≤ 9.59°, with the arm level. Swinging the waist from −60° to +60° (quintic, 20°/s: 11.25 s,
# q1 = −60 + 120·g(u), g = 10u³ − 15u⁴ + 6u⁵): at point 9 of 0..19 (u = 9/19, g = 0.45075) q1 = −5.91°, in it;
# at point 8 (u = 8/19) q1 = −17.47°, clear. The wrist and hand (r ≥ 1.15) never enter (x ≤ 0.7).
BOX = Obstacle.make("box", (0.5, -0.1, 0.2), (0.7, 0.1, 0.4))


def test_a_collision_is_reported_with_the_link_the_obstacle_and_the_point() -> None:
    seq = Sequencer([QuinticMove(_deg(60.0), None)], _deg(-60.0), _ctx(_bounds(Scene([BOX]))))
    err = seq.plan_error
    assert isinstance(err, MotionRefused) and err.code == "COLLISION"
    hits = {(r.link, r.obstacle): r for r in err.refusals}
    assert set(hits) == {("upper_arm", "box"), ("forearm", "box")}
    r = hits[("upper_arm", "box")]
    assert r.point_index == 9
    assert r.t_s == pytest.approx(11.25 * 9 / 19)
    assert math.degrees(r.theta_rad[0]) == pytest.approx(-5.91, abs=0.005)
    assert "link upper_arm hits obstacle box at point 10 of 20 (t = 5.329 s" in r.detail


def test_a_via_point_routes_around_the_obstacle() -> None:
    # up over it: the shoulder raised 45° puts the elbow at (0.42, 0, 0.72), the forearm above it
    route = LspbMove((_deg(-60.0, 45.0), _deg(60.0, 45.0), _deg(60.0)))
    seq = Sequencer([route], _deg(-60.0), _ctx(_bounds(Scene([BOX]))))
    assert seq.plan_error is None and len(seq.planned) == 1


def test_the_number_of_points_is_configurable_and_a_coarser_check_can_miss() -> None:
    # at 5 points (u = 0, ¼, ½, ¾, 1) the waist passes 0° at u = ½: still found; at 2 points only the
    # ends (±60°) are looked at and the collision between them is missed — why the paper takes 20
    bounds = _bounds(Scene([BOX]))
    bounds.points = 5
    assert isinstance(Sequencer([QuinticMove(_deg(60.0), None)], _deg(-60.0), _ctx(bounds)).plan_error, MotionRefused)
    bounds.points = 2
    assert Sequencer([QuinticMove(_deg(60.0), None)], _deg(-60.0), _ctx(bounds)).plan_error is None


def test_a_runtime_target_is_checked_as_one_pose() -> None:
    bounds = _bounds(Scene([BOX]))
    assert bounds.check_pose(_deg(30.0)) == []
    (r,) = [x for x in bounds.check_pose(_deg(0.0)) if x.link == "upper_arm"]
    assert (r.kind, r.obstacle) == ("collision", "box")
    assert [x.joint for x in bounds.check_pose(_deg(30.0, 0.0, 0.0, 0.0, 0.0, 0.0, 170.0))] == ["hand"]


# --- the scene file ----------------------------------------------------------------------------------------
def test_the_scene_file_is_read_and_refused_naming_the_key() -> None:
    scene = parse_scene(ConfigTable({"obstacle": [{"name": "a", "min_m": [0, 0, 0], "max_m": [1, 1, 1]}]}, "s.toml"))
    assert [o.name for o in scene.obstacles] == ["a"] and scene.obstacles[0].max_m == (1.0, 1.0, 1.0)
    with pytest.raises(ConfigError, match=r"obstacle\[0\]"):
        parse_scene(ConfigTable({"obstacle": [{"name": "a", "min_m": [0, 0, 2], "max_m": [1, 1, 1]}]}, "s.toml"))
    with pytest.raises(ConfigError, match=r"obstacle\[1\].*already"):
        parse_scene(ConfigTable({"obstacle": [{"name": "a", "min_m": [0, 0, 0], "max_m": [1, 1, 1]}] * 2}, "s.toml"))
    with pytest.raises(SceneError, match="no obstacle 'b'"):
        scene.remove("b")


def test_the_jpl_arm_ships_the_papers_twelve_obstacles_beside_its_rig_file() -> None:
    path = default_scene_path(resolve_rig("jpl-arm"))
    assert path.name == "jpl-arm.scene.toml"
    scene = load_scene(path)
    assert len(scene) == 12
    names = {o.name for o in scene.obstacles}
    assert {"ground", "platform", "electronics_rack", "tv_laser_assembly"} <= names
    # the arm level and straight ahead, and the default demo's targets, are clear of it
    bounds = _bounds(scene)
    assert bounds.collisions_at(_deg()) == []
    assert bounds.collisions_at(_deg(20.0, -15.0, 10.0, -10.0, 15.0, -20.0)) == []
    # pointing straight down from the shoulder (1.1 m below it) the tool is in the ground
    assert ("hand", "ground") in bounds.collisions_at(_deg(0.0, -90.0))


# --- a target known only at run time: visual servoing ------------------------------------------------------
class _Client:
    """The robot side of the vision protocol as the trajectory sees it: servoing once requested."""

    def __init__(self) -> None:
        from hal.bit3.protocol import RobotState

        self.state = RobotState.IDLE
        self.holding = False

    def request(self, now: float) -> None:
        from hal.bit3.protocol import RobotState

        self.state = RobotState.SERVOING

    def end(self, now: float) -> None:
        from hal.bit3.protocol import RobotState

        self.state = RobotState.IDLE


class _Link:
    """A vision link whose commands ask for the targets given, one per tick."""

    def __init__(self, targets: list[np.ndarray]) -> None:
        self.client = _Client()
        self.targets = list(targets)
        self.refused = 0
        self.last_refusal: str | None = None

    def clock(self) -> float:
        return 0.0

    def step(self, fallback: np.ndarray) -> np.ndarray | None:
        return self.targets.pop(0) if self.targets else None


def test_a_visual_servoing_target_past_a_limit_or_into_an_obstacle_is_not_used() -> None:
    from servo.vservo import VservoMove

    link = _Link([_deg(30.0, 10.0), _deg(30.0, 170.0), _deg(0.0), _deg(35.0, 12.0)])
    ctx = _ctx(_bounds(Scene([BOX])))
    ctx.extras["vision"] = link
    traj = VservoMove(timeout_s=10.0).build(_deg(30.0), ctx)
    seen = [math.degrees(traj.sample(k * 0.008).theta_d[1]) for k in range(4)]
    # 10° used; 170° (past the 160° limit) refused: held at 10°; q1 = 0 (the arm in BOX) refused: held
    assert seen == pytest.approx([10.0, 10.0, 10.0, 12.0])
    assert link.refused == 2 and "hits obstacle box" in (link.last_refusal or "")


def test_the_vision_summary_counts_refused_targets_even_when_none_were_refused() -> None:
    # docs/motion-safety.md: "the run's `vision.refused_targets` counts them" — a key a reader can
    # rely on, 0 in a run where every target was used (it was left out then)
    from servo.vservo import VisionLink

    client = _Client()
    client.end_reason = None  # type: ignore[attr-defined]  # the protocol's: None while the task runs
    link = VisionLink(client, ArmModel(), lambda: 0.0, lambda: None, 7)  # type: ignore[arg-type]
    summary = link.summary()
    assert summary["refused_targets"] == 0 and summary["last_refusal"] is None
    link.refused, link.last_refusal = 2, "move 1: joint j2 target 170.00° is past its soft limit"
    assert link.summary()["refused_targets"] == 2
