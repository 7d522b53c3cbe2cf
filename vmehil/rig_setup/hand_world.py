"""Give an emulated rig its hand's world: the scene's graspable objects (``[[object]]``) between
the fingers, their weight on the arm and the fingers' tactile switches (:mod:`emulators.grasp`)."""

from __future__ import annotations

from emulators.grasp import GraspWorld
from servo.scene import Scene
from servo.settings import ServoSettings
from vmehil.rig_setup.system import EmulatedRig


def attach_hand_world(system: EmulatedRig, scene: Scene | None, settings: ServoSettings) -> GraspWorld | None:
    """Attach the world when the rig states ``[arm]`` and ``[hand]`` and its plant is in this
    process; ``None`` otherwise (then nothing changes: no object, no switch is ever driven)."""
    if system.plant is None or settings.arm is None or settings.hand is None:
        return None
    hand = settings.hand
    joint = system.rig.joints[hand.joint]
    nets = tuple(joint.net(sig) for sig in ("tactile_left", "tactile_right") if sig in joint.wiring)
    objects = scene.objects if scene is not None else ()
    if not objects:  # nothing to grasp: the switches stay open, as without the world
        return None
    world = GraspWorld(system.plant, settings.arm, hand, objects, system.crate.signals, nets)
    system.grasp = world
    return world
