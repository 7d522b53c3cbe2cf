"""Assemble a servo loop for a rig: the servo parses its own settings from the rig file once
(:func:`servo.settings.servo_settings`, the keys are listed there and in docs/servo-loop.md) and
builds its own loop (:func:`servo.assembly.build_loop`); this module only puts the pieces
together for a rig the application built (emulated or on a real bus) and applies a command
line's override in the one place the settings take one
(:meth:`servo.settings.ServoSettings.overridden`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Protocol

from servo import assembly
from servo.boundary import PlantBoundary
from servo.io import JointIO
from servo.loop import ServoLoop
from servo.motion import Motion
from servo.rig import RigSpec
from servo.scene import Scene
from servo.settings import MIN_VELOCITY_DEG_S, ServoSettings, servo_settings
from servo.trajectory.sequencer import PlanContext, Sequencer

__all__ = ["MIN_VELOCITY_DEG_S", "AssembledRig", "ServoSettings", "build_loop",
           "plan_context_of", "servo_settings"]


class AssembledRig(PlantBoundary, Protocol):
    """A rig the application built: the plant boundary, the rig file and the joints' drivers
    (:class:`vmehil.rig_setup.system.EmulatedRig`, :class:`vmehil.rig_setup.real_bus.RealRig`)."""

    @property
    def rig(self) -> RigSpec: ...

    @property
    def io(self) -> JointIO: ...


def build_loop(system: AssembledRig, *, motion: Motion | None = None, gains: Mapping[str, float] | None = None,
               switch_off: bool | None = None, n_ticks: int = 0, watchdog: bool = True,
               sequencer: Sequencer | None = None, settings: ServoSettings | None = None,
               scene: Scene | None = None) -> ServoLoop:
    """A ready-to-start :class:`ServoLoop` for ``system``: ``settings`` (default: parsed from the
    rig file), with optional gain overrides applied to every joint and the switch-off forced on
    or off (:meth:`~servo.settings.ServoSettings.overridden`: a set the gain guard refuses raises
    :class:`~servo.gain_guard.GainRejected` and no loop is built).

    ``sequencer``: the motion already planned (a unit controller's segments of the global plan,
    :class:`servo.joint_groups.UnitSegments`); the joints are then not read here. ``scene``: the
    obstacles every move is checked against (:mod:`servo.scene`); a motion the soft limits or the
    scene refuse raises :class:`~servo.trajectory.bounds.MotionRefused` before anything is enabled."""
    base = settings if settings is not None else servo_settings(system.rig)
    if gains or switch_off is not None:
        base = base.overridden(gains, switch_off)
    return assembly.build_loop(system, system.io, base, motion=motion, n_ticks=n_ticks, watchdog=watchdog,
                               sequencer=sequencer, scene=scene)


def plan_context_of(loop: ServoLoop) -> PlanContext:
    """The limits ``loop`` plans new moves with (:func:`build_loop` always sets them)."""
    if loop.plan_context is None:
        raise RuntimeError("the servo loop has no plan context (it was not built by vmehil.rig_setup.session.build_loop)")  # noqa: E501  (a moved module's longer path; apply_moves.py)
    return loop.plan_context
