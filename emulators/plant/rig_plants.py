"""Plants from rig presets (``jpl-arm``, ``melmalec-16``) or rig-file paths."""

from __future__ import annotations

from collections.abc import Collection
from pathlib import Path

from emulators.plant.params import PlantParams, plant_params_from_config
from emulators.presets import resolve_rig
from hal.config import load_toml


def load_plant_params(rig: str | Path | None = None, *, foreign_keys: Collection[str] | None = None) -> PlantParams:
    """Plant parameters of a rig preset name or rig-file path (default: ``jpl-arm``);
    ``foreign_keys`` as for :func:`~emulators.plant.params.plant_params_from_config`.

    Errors: ``FileNotFoundError`` naming the presets, or ``hal.config.ConfigError`` naming the
    file and the key.
    """
    return plant_params_from_config(load_toml(resolve_rig(rig)), foreign_keys=foreign_keys)


def load_plant(rig: str | Path | None = None, *, seed: int = 0, rate_hz: float | None = None):
    """A :class:`emulators.plant.Plant` for a rig preset name or rig-file path."""
    from emulators.plant.plant import Plant

    return Plant(load_plant_params(rig), seed=seed, rate_hz=rate_hz)
