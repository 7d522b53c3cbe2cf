"""The servo builds its own loop: controller, motion, watchdog and recorder from its typed
settings (:mod:`servo.settings`), against the plant boundary and the drivers.

The application assembles (it builds the rig and the drivers, parses the settings once and may
override them) and hands the pieces here::

    settings = servo_settings(rig).overridden(gains, switch_off)
    loop = build_loop(plant, io, settings, motion=motion, n_ticks=n)

``plant`` is any :class:`servo.boundary.PlantBoundary` (the emulated rig, a real rig's wall
clock): the loop takes the plant's ``answer_lag_ticks`` (the watchdog's current check) and
``sample_clock`` (the cross-checks' time base) from it.
"""

from __future__ import annotations

import numpy as np

from hal.config import ConfigTable
from servo.blackbox import BlackBox
from servo.boundary import PlantBoundary
from servo.control.law import PidLaw
from servo.control.objects import CONTROL_OBJECTS, BaseControlObject, Controller, PidObject, TorqueLimit
from servo.io import JointIO
from servo.loop import Recorder, ServoLoop, WatchdogConfig
from servo.motion import Motion, default_demo_motion
from servo.scene import Scene
from servo.settings import ServoSettings
from servo.trajectory.base import JointLimits
from servo.trajectory.bounds import MotionBounds, MotionRefused
from servo.trajectory.sequencer import PlanContext, Sequencer

__all__ = ["build_controller", "build_loop", "motion_bounds", "plan_context", "watchdog_config"]


def build_controller(settings: ServoSettings) -> Controller:
    """The controller the settings name: its objects in order, normalized with the nominal chain."""
    objects: list[BaseControlObject] = []
    for name in settings.objects:
        if name == "pid":
            objects.append(PidObject(PidLaw(settings.n, settings.period_s, settings.gains, settings.switch_off,
                                            settings.filter_hz if settings.velocity_filter_hz else None)))
        elif name == "torque_limit":
            objects.append(TorqueLimit(np.asarray(settings.torque_limit_nm, float)))
        else:  # another object: its defaults ([servo] gives them no table)
            factory = CONTROL_OBJECTS[name]
            objects.append(factory(ConfigTable({}, f"{settings.source} (servo settings)", name), settings.n,
                                   settings.chain, settings.period_s))
    return Controller(objects, settings.chain, settings.period_s)


def watchdog_config(settings: ServoSettings, *, enabled: bool = True, answer_lag_ticks: int = 0) -> WatchdogConfig:
    """The watchdog's limits (NaN per joint: derived from the sensors when the loop is built)."""
    wd = WatchdogConfig(following_error_rad=np.asarray(settings.following_error_rad, float), enabled=enabled,
                        cross_checks=settings.watchdog.cross_checks)
    for key, value in settings.watchdog.rig_wide:
        setattr(wd, key, value)
    # a free-running plant node answers late; a real rig or an in-process plant does not
    wd.command_lag_ticks = int(answer_lag_ticks)
    for field, values in settings.watchdog.per_joint:
        setattr(wd, field, np.asarray(values, float))
    if len(settings.soft_min_rad) == settings.n:
        wd.soft_min_rad = np.asarray(settings.soft_min_rad, float)
        wd.soft_max_rad = np.asarray(settings.soft_max_rad, float)
    wd.soft_limit_margin_rad = settings.soft_limit_margin_rad
    return wd


def motion_bounds(settings: ServoSettings, scene: Scene | None = None) -> MotionBounds:
    """What every planned move must stay within: the soft limits and, with the rig's arm model,
    ``scene`` (``None``: an empty scene the console may add obstacles to)."""
    n = settings.n
    lo = settings.soft_min_rad if len(settings.soft_min_rad) == n else (-np.inf,) * n
    hi = settings.soft_max_rad if len(settings.soft_max_rad) == n else (np.inf,) * n
    if settings.arm is not None and scene is None:
        scene = Scene()
    return MotionBounds(settings.joint_names, np.asarray(lo, float), np.asarray(hi, float), settings.arm, scene,
                        settings.collision_points)


def plan_context(settings: ServoSettings, scene: Scene | None = None, *,
                 bounds: MotionBounds | None = None) -> PlanContext:
    """The limits moves are planned with (the planning velocity per joint) and what they must
    stay within (:func:`motion_bounds`; ``bounds`` given: those)."""
    return PlanContext(JointLimits.make(settings.n, list(settings.max_velocity_rad_s)),
                       bounds=bounds if bounds is not None else motion_bounds(settings, scene))


def build_loop(plant: PlantBoundary, io: JointIO, settings: ServoSettings, *, motion: Motion | None = None,
               n_ticks: int = 0, watchdog: bool = True, sequencer: Sequencer | None = None,
               scene: Scene | None = None) -> ServoLoop:
    """A ready-to-start :class:`ServoLoop` for the joints ``io`` drives.

    ``motion`` (default: the demo motion) is planned from the joints' angles read now;
    ``sequencer``: the motion already planned (a unit controller's segments of the global plan,
    :class:`servo.joint_groups.UnitSegments`) — the joints are then not read here. ``n_ticks`` > 0 adds a
    recorder of that many ticks; ``watchdog=False`` disables the watchdog's stops. ``scene``: the
    obstacles moves are checked against (:mod:`servo.scene`; ``None``: none yet).

    A motion whose moves the soft limits or the scene refuse raises
    :class:`~servo.trajectory.bounds.MotionRefused` here, before any amplifier is enabled. The loop
    always keeps a black box of the last ``settings.blackbox_s`` seconds (:mod:`servo.blackbox`)."""
    controller = build_controller(settings)
    bounds = motion_bounds(settings, scene)
    ctx = plan_context(settings, bounds=bounds)
    if sequencer is None:
        motion = motion or default_demo_motion(settings.n)
        sequencer = Sequencer(list(motion.moves), io.read().theta, ctx)
        if isinstance(sequencer.plan_error, MotionRefused):
            raise sequencer.plan_error
    wd = watchdog_config(settings, enabled=watchdog, answer_lag_ticks=plant.answer_lag_ticks)
    recorder = Recorder(n_ticks, settings.n) if n_ticks else None
    loop = ServoLoop(io, controller, sequencer, wd, recorder=recorder, names=list(settings.joint_names),
                     plan_context=plan_context(settings, bounds=bounds))
    loop.stop_settings = settings.stop
    loop.require_homing = settings.require_homing
    if settings.controllers is not None:  # the named controllers per joint, the rig's default active
        loop.controllers = settings.controllers
        loop.active_controller = list(settings.controllers.start)
    loop.hand_model = settings.hand
    # always kept: the last seconds before any stop (servo.blackbox; no bus access of its own)
    loop.blackbox = BlackBox(settings.n, settings.period_s, settings.joint_names, seconds=settings.blackbox_s)
    # an emulated rig's free-running plant: its answers may skip or repeat plant steps
    loop.sample_clock = plant.sample_clock
    return loop
