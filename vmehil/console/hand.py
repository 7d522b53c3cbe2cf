"""The hand on the console: ``open``, ``close``, ``squeeze [AMPS]``, ``grasp [OBJECT]`` and
``weigh`` — the JPL operators' finger commands (docs/hand.md).

``open``/``close``/``squeeze`` put the hand joint in its current-command mode
(:class:`servo.hand.HandCurrent`) at the next tick; each is complete (for a compound sequence)
once the hand has come to rest. ``open`` also starts the window of the arm's measured holding
torques (:class:`servo.hand.TorqueWindow`); ``close`` keeps its mean as the baseline without the
object; ``weigh`` compares the window now with it, through the arm's Jacobian
(:func:`servo.hand.estimate_mass`). ``grasp`` checks the tactile switches against the hand pot
(:func:`servo.hand.check_grasp`): ``ERR GRASP`` when they disagree.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from servo.hand import REST_SPEED_RAD_S, HandCurrent, HandError, TorqueWindow, check_grasp, estimate_mass
from vmehil.console.protocol import GRASP, STATE, UNAVAILABLE, VALUE, ConsoleError, kv

#: a finger command is complete (for a compound sequence) once the hand has been at rest
#: (servo.hand.REST_SPEED_RAD_S) this many ticks and, when the torque window runs, the window is full
REST_TICKS = 25
#: the holding torques are averaged over this long (s): the imon noise's standard error falls as 1/√n
WINDOW_S = 1.0
#: [assumed] the friction allowance of a holding torque: the joints' breakout friction is ≈ 5 % of
#: their peak torques (jpl-arm's [joint.friction], docs/plant.md); a held joint's torque may sit
#: anywhere within ± of it, before and after the object came on
FRICTION_FRACTION = 0.05
#: the arm must not move between the close and the weigh by more than this (rad): the same pose, near
#: enough the same Jacobian (a 1 kg load sags jpl-arm's shoulder ≈ 0.6° before its servo takes it up)
SAME_POSE_RAD = math.radians(2.0)


def _hand_model(loop: Any) -> Any:
    hand = getattr(loop, "hand_model", None)
    if hand is None:
        raise ConsoleError(UNAVAILABLE, "this rig's file states no [hand]: no finger commands (docs/hand.md)")
    return hand


def _at_rest(joint: int) -> Any:
    quiet = [0]

    def until(loop: Any) -> bool:
        if loop.fault is not None or not loop.enabled:
            return True
        w = (loop.last or {}).get("omega")
        if w is None or not np.isfinite(w[joint]) or abs(float(w[joint])) >= REST_SPEED_RAD_S:
            quiet[0] = 0
            return False
        quiet[0] += 1
        w = loop.torque_window
        return quiet[0] >= REST_TICKS and (w is None or w.full)
    return until


def finger(loop: Any, action: str, amps: float | None, source: str,
           require_running: Callable[[Any], None]) -> tuple[list[str], str, Callable[[Any], bool]]:
    """``open``/``close``/``squeeze``: reply lines, the OK text and when it is complete."""
    hand = _hand_model(loop)
    require_running(loop)
    limit = float(loop.io.scaling[hand.joint].current_limit_a)
    try:
        cmd = HandCurrent.make(hand.joint, action, amps, limit)
    except HandError as e:
        raise ConsoleError(VALUE, str(e)) from None
    lines = []
    if action == "open" and loop.torque_window is None:
        s_ = loop.io.scaling
        loop.torque_window = TorqueWindow(np.array([x.ratio * x.kt_nm_per_a for x in s_]),
                                          max(2, round(WINDOW_S / loop.period_s)))
    if action == "close":
        w = loop.torque_window
        theta = (loop.last or {}).get("theta")
        if w is None or theta is None or not w.mark_baseline(theta):
            lines.append(kv("INFO", f"no weigh baseline: open and hold {WINDOW_S:g} s before closing to weigh"))
    loop.set_hand(cmd)
    loop.note(source, f"hand {action} at {cmd.current_a:g} A")
    return lines, kv(action=action, current_a=cmd.current_a), _at_rest(hand.joint)


def _grasp_state(loop: Any) -> tuple[float, list[bool]]:
    """The fingertip gap the hand pot reads (m) and the tactile switches (closed = True)."""
    hand = _hand_model(loop)
    m = loop.io.read()
    gap = hand.gap_m(float(m.theta_pot[hand.joint]))
    joint = loop.io.rig.joints[hand.joint]
    switches = [bool(loop.io.pio[joint.wiring[sig].board].get_line(joint.net(sig)))
                for sig in ("tactile_left", "tactile_right") if sig in joint.wiring]
    return gap, switches


def _object_width(loop: Any, name: str | None) -> float | None:
    if name is None:
        return None
    bounds = getattr(getattr(loop, "plan_context", None), "bounds", None)
    scene = getattr(bounds, "scene", None)
    for obj in getattr(scene, "objects", ()):
        if obj.name == name:
            return float(obj.width_m)
    raise ConsoleError(VALUE, f"no object {name!r} in the scene")


def grasp(loop: Any, name: str | None) -> str:
    """``grasp [OBJECT]``: the OK text, or ``ERR GRASP`` (:class:`ConsoleError`) saying why not."""
    hand = _hand_model(loop)
    width = _object_width(loop, name)
    gap, switches = _grasp_state(loop)
    why = check_grasp(gap, switches, hand.grasp_tolerance_m, width)
    if why is not None:
        raise ConsoleError(GRASP, why)
    return kv(gap_mm=round(gap * 1e3, 2), switches=",".join("closed" if c else "open" for c in switches))


def weigh(loop: Any, source: str, require_running: Callable[[Any], None]) -> str:
    """``weigh``: the OK text (``mass_kg=… uncertainty_kg=…``)."""
    hand = _hand_model(loop)
    require_running(loop)
    arm = getattr(getattr(loop.plan_context, "bounds", None), "arm", None)
    if arm is None:
        raise ConsoleError(UNAVAILABLE, "weigh: this rig's file states no [arm]: no Jacobian")
    gap, switches = _grasp_state(loop)
    if not (switches and all(switches)):
        raise ConsoleError(STATE, "weigh: nothing held (the tactile switches are open): close on the object first")
    why = check_grasp(gap, switches, hand.grasp_tolerance_m)
    if why is not None:
        raise ConsoleError(GRASP, why)
    w = loop.torque_window
    if w is None or w.baseline is None:
        raise ConsoleError(STATE, f"weigh: no baseline: open, hold {WINDOW_S:g} s, close on the object, then weigh")
    if not w.full:
        raise ConsoleError(STATE, f"weigh: the hand has not been at rest {WINDOW_S:g} s since it moved: wait, "
                                  "then weigh")
    base, base_se, theta0 = w.baseline
    theta = np.asarray(loop.last["theta"], float)
    arm_joints = [*arm.joints, *arm.wrist_joints]
    moved = float(np.max(np.abs(theta[arm_joints] - theta0[arm_joints])))
    if moved > SAME_POSE_RAD:
        raise ConsoleError(STATE, f"weigh: the arm moved {math.degrees(moved):.2f}° since the close: weigh in the pose "
                                  "the hand closed in")
    limit = np.array([x.current_limit_a * x.ratio * x.kt_nm_per_a for x in loop.io.scaling])  # peak torque (N·m)
    friction = FRICTION_FRACTION * limit * math.sqrt(2.0 / 3.0)  # two draws, each uniform in ± the allowance
    sigma = np.sqrt(np.square(w.std_of_mean()) + np.square(base_se) + np.square(friction))
    try:
        est = estimate_mass(w.mean() - base, arm.tool_jacobian(theta), sigma, arm_joints)
    except HandError as e:
        raise ConsoleError(STATE, str(e)) from None
    loop.note(source, f"weigh {est.mass_kg:.3f} ± {est.uncertainty_kg:.3f} kg")
    return kv(mass_kg=round(est.mass_kg, 4), uncertainty_kg=round(est.uncertainty_kg, 4))
