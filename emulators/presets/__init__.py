"""Shipped rig presets (TOML) and their scenes (``<rig>.scene.toml``, servo.scene). A rig is named
(``jpl-arm``) or given by path."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

DEFAULT_RIG = "jpl-arm"
#: a rig's scene file beside it (servo.scene): not a preset of its own
SCENE_SUFFIX = ".scene.toml"


def preset_names() -> list[str]:
    return sorted(
        p.name[: -len(".toml")]
        for p in resources.files(__package__).iterdir()
        if p.name.endswith(".toml") and not p.name.endswith(SCENE_SUFFIX)
    )


def resolve_rig(name_or_path: str | Path | None) -> Path:
    """Path of a preset name (``jpl-arm``) or of an existing file; ``FileNotFoundError`` names
    the presets when neither matches."""
    target = str(name_or_path or DEFAULT_RIG)
    p = Path(target)
    if p.suffix == ".toml" or p.exists():
        if not p.exists():
            raise FileNotFoundError(f"rig file {p} does not exist")
        return p
    res = resources.files(__package__) / f"{target}.toml"
    if not res.is_file():
        raise FileNotFoundError(
            f"no rig preset named {target!r} (presets: {', '.join(preset_names())}); "
            "give a preset name or a path to a .toml file"
        )
    return Path(str(res))
