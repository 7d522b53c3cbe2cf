"""The scene: the obstacles a planned move must not touch, as the JPL paper keeps them.

"Each of these obstacles is described by the circumscribing rectangular envelope with sides
aligned with the manipulator base coordinate system" — an n×6 array of (x, y, z) minima and
maxima; "nonpermanent obstacles detected by the robot environment sensors are added to the
obstacle array; the collision detection software remains unchanged". A scene file (TOML, metres
in the arm's base frame)::

    [[obstacle]]
    name = "platform"
    min_m = [-0.9, -0.5, -0.45]
    max_m = [-0.1, 0.5, -0.02]

    [[object]]                     # a graspable object (the hand: docs/hand.md)
    name = "sample"
    width_m = 0.04                 # across the fingers
    mass_kg = 0.5
    stiffness_n_per_m = 5000.0     # across the fingers: a close stops on contact
    position_m = [0.9, 0.0, 0.2]   # the tool point must be within the hand's capture radius

``vmehil run|plan --scene PATH``; by default the rig file's ``<rig>.scene.toml`` beside it when
one exists (:func:`default_scene_path`). Obstacles come and go at run time (the console's
``obstacle add|remove``): a :class:`Scene` is the one mutable list the planner reads.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from hal.config import ConfigTable, load_toml
from hal.hand import GraspObject
from servo.errors import ServoError

__all__ = ["MAX_OBSTACLES", "GraspObject", "Obstacle", "Scene", "SceneError", "default_scene_path", "load_scene",
           "parse_scene"]

#: the most obstacles a scene holds (the paper's arm had twelve permanent ones)
MAX_OBSTACLES = 1000
#: an obstacle's name: a word (the console's ``obstacle remove NAME`` takes it back)
NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_.-]{0,63}\Z")
#: no coordinate is further than this from the base (m): a sanity bound, not a reach
MAX_COORD_M = 1000.0


class SceneError(ServoError, ValueError):
    """An obstacle that cannot be added (bad name, a name taken, bad box) or removed (unknown)."""


@dataclass(frozen=True)
class Obstacle:
    """An axis-aligned box in the arm's base frame (m): ``min_m`` ≤ P ≤ ``max_m``."""

    name: str
    min_m: tuple[float, float, float]
    max_m: tuple[float, float, float]

    @classmethod
    def make(cls, name: str, min_m: tuple[float, ...] | list[float],
             max_m: tuple[float, ...] | list[float]) -> Obstacle:
        """A checked obstacle; :class:`SceneError` says what is wrong."""
        if not isinstance(name, str) or not NAME_RE.match(name):
            raise SceneError(f"obstacle name {name!r}: a word of letters, digits, _ . - (at most 64)")
        lo, hi = tuple(float(x) for x in min_m), tuple(float(x) for x in max_m)
        if len(lo) != 3 or len(hi) != 3:
            raise SceneError(f"obstacle {name}: min_m and max_m are [x, y, z] in metres")
        if not all(math.isfinite(v) and abs(v) <= MAX_COORD_M for v in (*lo, *hi)):
            raise SceneError(f"obstacle {name}: coordinates must be finite, within ±{MAX_COORD_M:g} m")
        if not all(a < b for a, b in zip(lo, hi, strict=True)):
            raise SceneError(f"obstacle {name}: each of min_m {list(lo)} must be below max_m {list(hi)}")
        return cls(name, lo, hi)  # type: ignore[arg-type]


class Scene:
    """The obstacles, by name, in the order they were added. ``source``: where they came from."""

    def __init__(self, obstacles: list[Obstacle] | tuple[Obstacle, ...] = (), source: str = "<no scene>",
                 objects: list[GraspObject] | tuple[GraspObject, ...] = ()) -> None:
        self.source = source
        self._obstacles: dict[str, Obstacle] = {}
        for ob in obstacles:
            self.add(ob)
        #: the graspable objects (``[[object]]``), by name: not obstacles (the hand closes on them)
        self._objects: dict[str, GraspObject] = {}
        for obj in objects:
            self.add_object(obj)

    @property
    def objects(self) -> tuple[GraspObject, ...]:
        """The graspable objects, in the order they were added."""
        return tuple(self._objects.values())

    def add_object(self, obj: GraspObject) -> None:
        """Add a graspable object; a name already in the scene (object or obstacle) is refused."""
        if obj.name in self._objects or obj.name in self._obstacles:
            raise SceneError(f"object {obj.name!r}: the name is already in the scene")
        if len(self._objects) >= MAX_OBSTACLES:
            raise SceneError(f"the scene holds at most {MAX_OBSTACLES} objects")
        self._objects[obj.name] = obj

    @property
    def obstacles(self) -> tuple[Obstacle, ...]:
        return tuple(self._obstacles.values())

    def __len__(self) -> int:
        return len(self._obstacles)

    def add(self, obstacle: Obstacle) -> None:
        """Add ``obstacle``; a name already in the scene is refused (remove it first)."""
        if obstacle.name in self._obstacles:
            raise SceneError(f"obstacle {obstacle.name!r} is already in the scene (remove it first)")
        if len(self._obstacles) >= MAX_OBSTACLES:
            raise SceneError(f"the scene holds at most {MAX_OBSTACLES} obstacles")
        self._obstacles[obstacle.name] = obstacle

    def remove(self, name: str) -> Obstacle:
        """Take obstacle ``name`` out (returned); an unknown name is refused."""
        try:
            return self._obstacles.pop(name)
        except KeyError:
            known = ", ".join(self._obstacles) or "none"
            raise SceneError(f"no obstacle {name!r} in the scene (obstacles: {known})") from None


def parse_scene(cfg: ConfigTable) -> Scene:
    """A scene table (``[[obstacle]] name, min_m, max_m``; ``[[object]] name, width_m, mass_kg,
    stiffness_n_per_m, position_m``); :class:`hal.config.ConfigError` names the file and key of
    anything wrong."""
    cfg.check_unknown({"obstacle", "object", "description"})
    scene = Scene(source=cfg.source)
    for ob in cfg.tables("obstacle", []):
        ob.check_unknown({"name", "min_m", "max_m", "note"})
        name = ob.get_str("name")
        try:
            scene.add(Obstacle.make(name, ob.floats("min_m", length=3), ob.floats("max_m", length=3)))
        except SceneError as e:
            raise ob.error("name", str(e), name) from None
    for ot in cfg.tables("object", []):
        ot.check_unknown({"name", "width_m", "mass_kg", "stiffness_n_per_m", "position_m", "note"})
        name = ot.get_str("name")
        try:
            obj = GraspObject.make(name, ot.get_float("width_m"), ot.get_float("mass_kg"),
                                   ot.get_float("stiffness_n_per_m"), ot.floats("position_m", length=3))
            scene.add_object(obj)
        except (SceneError, ValueError) as e:
            raise ot.error("name", str(e), name) from None
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read and parse a scene file."""
    return parse_scene(load_toml(path))


def default_scene_path(rig_path: str | Path) -> Path:
    """The scene file that goes with a rig file: ``<rig>.scene.toml`` beside it."""
    p = Path(rig_path)
    return p.with_name(p.name.removesuffix(".toml") + ".scene.toml")
