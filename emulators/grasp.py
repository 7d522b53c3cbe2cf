"""The hand's world: a graspable object between the fingers, its weight on the arm, and the
fingers' tactile switches.

Once per servo period, before the plant steps (:meth:`GraspWorld.before_period`), from the
plant's true joint angles:

* **Contact.** An object is *between the fingers* when the tool point (:mod:`hal.kinematics`)
  is within the hand's capture radius of the object's position, or while it is held. The
  fingers meet it when their gap (:class:`hal.hand.HandModel`) closes to its width: the plant's
  hand joint gets a one-sided spring there (:meth:`emulators.plant.Plant.set_contact`),
  ``k·(d gap/dθ)²`` N·m/rad from the object's stiffness across the fingers, evaluated every
  substep — so a close stops on contact and a squeeze compresses the object by ``F/k``.
* **Weight.** While the fingers press on it (contact force > 0; friction is taken as
  sufficient) the object is *held*: it rides at the tool point and its weight ``F = (0, 0,
  −m·g)`` loads every arm joint through the kinematics, ``τ = Jᵀ·F`` (the tool point's Jacobian),
  applied as the plant's external torque for the period (the arm moves little in 8 ms). When
  the fingers let go it stays where it was released.
* **Tactile switches.** After each period (:meth:`publish`) each finger's switch net is driven
  high while the finger force exceeds the hand's ``tactile_threshold_n`` (both fingers feel the
  same force: the gripper is symmetric). The nets are inputs of a PIO board (jpl-arm: pio1 PB0,
  PB1), read by the drivers like any input line — a ``line_stuck`` fault on the board holds one.

Only for an in-process plant (the world reads and sets the plant object itself).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from emulators.plant import Plant
from emulators.signals import Signals
from hal.hand import GRAVITY_M_S2, GraspObject, HandModel
from hal.kinematics import ArmModel

__all__ = ["GraspWorld"]


@dataclass
class _Held:
    """An object of the world and where it is now (m, base frame)."""

    obj: GraspObject
    position_m: np.ndarray
    held: bool = False


@dataclass
class GraspWorld:
    """The objects and the fingers of one emulated rig (see the module docstring)."""

    plant: Plant
    arm: ArmModel
    hand: HandModel
    objects: Sequence[GraspObject]
    signals: Signals | None = None
    #: the tactile switches' nets (``[joint.wiring] tactile_left`` / ``tactile_right``)
    switch_nets: tuple[str, ...] = ()
    _items: list[_Held] = field(default_factory=list, init=False)
    #: the object between the fingers now (``None``: none), and the finger force at the last period's end (N)
    between: GraspObject | None = field(default=None, init=False)
    finger_force_n: float = field(default=0.0, init=False)

    def __post_init__(self) -> None:
        self._items = [_Held(o, np.asarray(o.position_m, float).copy()) for o in self.objects]
        self._base_external = np.asarray(self.plant.external_torque_nm, float).copy()

    def _candidate(self, theta: np.ndarray) -> _Held | None:
        for it in self._items:
            if it.held:
                return it
        tool = self.arm.tool_position(theta)
        near = [(float(np.linalg.norm(tool - it.position_m)), k) for k, it in enumerate(self._items)]
        near = [(d, k) for d, k in near if d <= self.hand.capture_radius_m]
        return self._items[min(near)[1]] if near else None

    def before_period(self) -> None:
        """Set the plant's contact spring and the held object's weight for the coming period."""
        p = self.plant
        theta = p.joint_angle()
        h = self.hand.joint
        it = self._candidate(theta)
        self.between = it.obj if it is not None else None
        k = np.zeros(p.n_joints)
        at = np.zeros(p.n_joints)
        force = 0.0
        if it is not None:
            k[h] = self.hand.joint_stiffness_nm_per_rad(it.obj.stiffness_n_per_m)
            at[h] = self.hand.angle_rad(it.obj.width_m)
            force = max(0.0, it.obj.stiffness_n_per_m * (it.obj.width_m - self.hand.gap_m(float(theta[h]))))
            was = it.held
            it.held = force > 0.0
            if it.held:
                it.position_m = self.arm.tool_position(theta)
            elif was:  # released: it stays where the hand let go of it
                it.position_m = self.arm.tool_position(theta)
        if bool(np.any(k != p.contact_k_nm_per_rad)) or bool(np.any(at != p.contact_rad)):
            p.set_contact(k, at)
        ext = self._base_external.copy()
        if it is not None and it.held and it.obj.mass_kg > 0.0:
            weight = np.array([0.0, 0.0, -it.obj.mass_kg * GRAVITY_M_S2])
            ext = ext + self.arm.tool_jacobian(theta).T @ weight
        if bool(np.any(ext != p.external_torque_nm)):
            p.set_external_torque(ext)

    def publish(self) -> None:
        """Drive the tactile switches' nets from the finger force at the end of the period."""
        p = self.plant
        theta = p.joint_angle()
        h = self.hand.joint
        it = self.between
        force = 0.0
        if it is not None:
            force = max(0.0, it.stiffness_n_per_m * (it.width_m - self.hand.gap_m(float(theta[h]))))
        self.finger_force_n = force
        if self.signals is not None:
            closed = force > self.hand.tactile_threshold_n
            for net in self.switch_nets:
                if self.signals.get_digital(net) != closed:
                    self.signals.set_digital(net, closed)

    def held(self) -> GraspObject | None:
        """The object the hand holds now (``None``: none)."""
        return next((it.obj for it in self._items if it.held), None)

    def position_of(self, name: str) -> np.ndarray:
        """Where object ``name`` is now (m, base frame)."""
        for it in self._items:
            if it.obj.name == name:
                return it.position_m.copy()
        raise KeyError(name)
