"""An alias: this package moved.

Now :mod:`vmehil.unit_controllers`
(docs/architecture.md); this alias package keeps the old path
``vmehil.units``
and its modules importable for one release (CHANGELOG.md, "Moved modules"); import the new path
instead.
Each module under it is the moved module itself; a name of the package is looked up in the new one.
"""

# moves: alias written by apply_moves.py — do not edit; remove it in the release after next.

import importlib
from typing import Any

_moved = importlib.import_module("vmehil.unit_controllers")


def __getattr__(name: str) -> Any:
    return getattr(_moved, name)
