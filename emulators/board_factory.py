"""What a board type is: a factory that builds a board from its crate-file table."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from emulators.board import Board
from emulators.signals import Signals
from hal.config import ConfigTable

BoardFactory = Callable[[str, ConfigTable, "BuildContext"], Board]
"""``factory(name, cfg, ctx) -> Board``: ``cfg`` is the board's ``[[crate.board]]`` table (its
type-specific keys; unknown keys are refused after the factory returns)."""


@dataclass
class BuildContext:
    """What a board factory may need besides its own table."""

    signals: Signals
    seed: int = 0
