"""Board types that crate files can name (``type = "adc"``) and their config factories."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from emulators.board import Board
from emulators.signals import Signals
from hal.config import ConfigTable

BoardFactory = Callable[[str, ConfigTable, "BuildContext"], Board]


@dataclass
class BuildContext:
    """What a board factory may need besides its own table."""

    signals: Signals
    seed: int = 0


_TYPES: dict[str, BoardFactory] = {}


def register_board_type(type_name: str, factory: BoardFactory) -> None:
    if type_name in _TYPES:
        raise ValueError(f"board type {type_name!r} registered twice")
    _TYPES[type_name] = factory


def board_factory(type_name: str) -> BoardFactory | None:
    _load_builtin()
    return _TYPES.get(type_name)


def board_types() -> list[str]:
    _load_builtin()
    return sorted(_TYPES)


def _load_builtin() -> None:
    # Importing the board modules registers their factories.
    import emulators.builtin_boards  # noqa: F401
