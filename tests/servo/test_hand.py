"""servo.hand and the scene's [[object]]: the grasp check's verdicts, the mass estimate against a
hand-computed load, the current command's limits, and the scene parser's objects."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hal.config import ConfigError, ConfigTable
from hal.kinematics import ArmModel
from servo.hand import HandCurrent, HandError, TorqueWindow, check_grasp, estimate_mass
from servo.scene import parse_scene

TOL = 0.006


def test_switches_closed_at_the_objects_width_is_a_good_grasp() -> None:
    assert check_grasp(0.0405, [True, True], TOL, 0.04) is None


def test_switches_closed_but_the_pot_wider_than_the_object_is_refused() -> None:
    why = check_grasp(0.05, [True, True], TOL, 0.04)
    assert why is not None and "wider than the object (40.0 mm)" in why


def test_switches_closed_but_the_pot_says_shut_is_refused() -> None:
    why = check_grasp(0.003, [True, True], TOL)
    assert why is not None and "fingers are shut" in why


def test_one_switch_closed_one_open_is_refused() -> None:
    why = check_grasp(0.04, [True, False], TOL, 0.04)
    assert why is not None and "the tactile switches disagree (closed, open)" in why


def test_the_pot_closed_on_nothing_is_refused() -> None:
    why = check_grasp(0.0035, [False, False], TOL)
    assert why is not None and "closed on nothing" in why


def test_the_mass_estimate_inverts_a_hand_computed_load() -> None:
    # arm straight out at the shoulder's height: the tool point 1.4 m from the shoulder axis,
    # 0.8 m from the elbow's, 0.25 m from the wrist pitch's; 2 kg: Δτ = m·g·r on j2, j3, j4
    arm = ArmModel()
    theta = np.zeros(7)
    g = 9.80665
    dtau = np.array([0.0, 2.0 * g * 1.4, 2.0 * g * 0.8, 2.0 * g * 0.25, 0.0, 0.0, 0.0])
    sigma = np.full(7, 0.1)
    est = estimate_mass(dtau, arm.tool_jacobian(theta), sigma, [0, 1, 2, 3, 4, 5])
    assert est.mass_kg == pytest.approx(2.0, rel=1e-9)
    # σ_m = σ / (g·√(1.4² + 0.8² + 0.25²))
    assert est.uncertainty_kg == pytest.approx(0.1 / (g * math.sqrt(1.4**2 + 0.8**2 + 0.25**2)), rel=1e-9)


def test_a_current_above_the_amplifiers_limit_is_refused() -> None:
    with pytest.raises(HandError, match="at most the amplifier's limit 2 A"):
        HandCurrent.make(6, "squeeze", 2.5, 2.0)
    assert HandCurrent.make(6, "close", None, 2.0).signed_a == -0.5  # closing: towards 0 rad
    assert HandCurrent.make(6, "open", None, 2.0).signed_a == 0.5


def test_the_fingers_top_speed_withholds_the_current() -> None:
    c = HandCurrent.make(6, "close", 1.0, 2.0)
    assert c.current_at(-0.3) == -1.0  # closing at 0.3 rad/s: under 0.5 rad/s
    assert c.current_at(-0.6) == 0.0


def test_the_torque_window_restarts_while_the_hand_moves() -> None:
    w = TorqueWindow(np.array([2.0, 3.0]), 3)
    for _ in range(3):
        w.add(np.array([1.0, 1.0]))
    assert w.full and list(w.mean()) == [2.0, 3.0]
    w.add(np.array([1.0, 1.0]), hand_speed_rad_s=0.5)
    assert not w.full


def test_a_scene_file_gives_its_objects() -> None:
    cfg = ConfigTable({"object": [{"name": "sample", "width_m": 0.04, "mass_kg": 0.5, "stiffness_n_per_m": 5000.0,
                                   "position_m": [0.9, 0.0, 0.2]}]}, "s.toml")
    scene = parse_scene(cfg)
    (obj,) = scene.objects
    assert (obj.name, obj.width_m, obj.mass_kg, obj.stiffness_n_per_m, obj.position_m) == (
        "sample", 0.04, 0.5, 5000.0, (0.9, 0.0, 0.2))
    assert len(scene) == 0  # an object is not an obstacle


@pytest.mark.parametrize("bad", [{"width_m": -0.01}, {"mass_kg": -1.0}, {"stiffness_n_per_m": 0.0},
                                 {"position_m": [0.0, 0.0]}, {"grip": 1}])
def test_a_bad_object_is_refused_naming_the_file(bad: dict) -> None:
    obj = {"name": "sample", "width_m": 0.04, "mass_kg": 0.5, "stiffness_n_per_m": 5000.0,
           "position_m": [0.9, 0.0, 0.2], **bad}
    with pytest.raises(ConfigError, match="s.toml"):
        parse_scene(ConfigTable({"object": [obj]}, "s.toml"))


def test_a_hand_table_with_an_unknown_key_is_refused() -> None:
    from hal.hand import HandModel

    with pytest.raises(ConfigError, match="grip"):
        HandModel.from_table(ConfigTable({"joint": 6, "grip": 1.0}, "rig.toml", "hand"))


def test_a_hand_joint_the_rig_has_not_is_refused(tmp_path) -> None:
    from emulators.presets import resolve_rig
    from servo.rig import load_rig
    from servo.settings import servo_settings

    text = resolve_rig("jpl-arm").read_text(encoding="utf-8")
    path = tmp_path / "rig.toml"
    path.write_text(text.replace("joint = 6                        # the hand joint", "joint = 9  # the hand joint", 1),
                    encoding="utf-8")
    with pytest.raises(ConfigError, match="a joint of the rig"):
        servo_settings(load_rig(path))
