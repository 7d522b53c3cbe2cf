"""An alias: this module moved.

Now :mod:`emulators.plant.link_dynamics`
(docs/architecture.md); this alias keeps the old path
``emulators.plant.link``
importable for one release (CHANGELOG.md, "Moved modules"); import the new path instead.

Importing it gives the moved module itself — the same module object, so attributes, monkeypatching
and isinstance agree — and ``python -m emulators.plant.link`` runs the moved module as ``__main__``.
"""

# moves: alias written by apply_moves.py — do not edit; remove it in the release after next.

import importlib
import sys

if __name__ == "__main__":
    import runpy

    runpy.run_module("emulators.plant.link_dynamics", run_name="__main__", alter_sys=True)
else:
    sys.modules[__name__] = importlib.import_module("emulators.plant.link_dynamics")
