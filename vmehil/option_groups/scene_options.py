"""``--scene PATH``: the obstacles every planned move is checked against (docs/motion-safety.md),
shared by ``vmehil run``, ``vmehil console`` and ``vmehil plan``.

Without the flag a rig's own scene is used when there is one: ``<rig>.scene.toml`` beside the rig
file (the jpl-arm preset ships ``emulators/presets/jpl-arm.scene.toml``). ``--scene none``: no
obstacles (the console may still add some).
"""

from __future__ import annotations

import argparse

from servo.rig import RigSpec
from servo.scene import Scene, default_scene_path, load_scene
from servo.settings import ServoSettings
from vmehil.errors import CliError

__all__ = ["NO_SCENE", "add_scene_argument", "resolve_scene"]

#: the ``--scene`` value that means "no obstacles, not even the rig's own scene"
NO_SCENE = "none"


def add_scene_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scene", metavar="PATH|none", default=None,
                   help="obstacles (TOML: [[obstacle]] name, min_m, max_m) every move is checked against "
                        "(default: <rig>.scene.toml beside the rig file when it exists; none: no obstacles)")


def resolve_scene(option: str | None, rig: RigSpec, settings: ServoSettings) -> Scene | None:
    """The scene of a command: ``--scene PATH`` (refused for a rig whose file states no ``[arm]``:
    there are no links to check), ``none``, or the rig's own scene file when it exists."""
    if option == NO_SCENE:
        return None
    if option is not None:
        if settings.arm is None:
            raise CliError(f"--scene {option}: rig {rig.name} ({rig.path}) states no [arm]: no links to check "
                           "against obstacles")
        return load_scene(option)
    default = default_scene_path(rig.path)
    if settings.arm is not None and default.is_file():
        return load_scene(default)
    return None
