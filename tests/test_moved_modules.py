"""The moved modules (written by apply_moves.py, issue #27): each old import path is the moved
module itself, and ``python -m`` on an old path runs the moved module as ``__main__``."""

from __future__ import annotations

import importlib
import importlib.util
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support import REPO

MOVED = {
    'emulators.can.link': 'emulators.can.can_plant_link',
    'emulators.plant.analysis': 'emulators.plant.friction_metrics',
    'emulators.plant.link': 'emulators.plant.link_dynamics',
    'emulators.plant.presets': 'emulators.plant.rig_plants',
    'hal.units': 'hal.si',
    'servo.units': 'servo.joint_groups',
    'vmehil.analysis.loop': 'vmehil.analysis.loop_model',
    'vmehil.ascii_text': 'vmehil.writers.ascii_text',
    'vmehil.can_options': 'vmehil.option_groups.can_options',
    'vmehil.cli_types': 'vmehil.option_groups.cli_types',
    'vmehil.commands.units': 'vmehil.commands.unit_coordinate',
    'vmehil.emulated_calibration': 'vmehil.rig_setup.emulated_calibration',
    'vmehil.fault_injection': 'vmehil.fault_scenarios.injection',
    'vmehil.fault_options': 'vmehil.fault_scenarios.options',
    'vmehil.files': 'vmehil.writers.files',
    'vmehil.friction_id': 'vmehil.analysis.friction_id',
    'vmehil.metrics': 'vmehil.reports.metrics',
    'vmehil.outputs': 'vmehil.writers.output_paths',
    'vmehil.progress': 'vmehil.writers.progress',
    'vmehil.real_bus': 'vmehil.rig_setup.real_bus',
    'vmehil.realtime_options': 'vmehil.option_groups.realtime_options',
    'vmehil.reproduce': 'vmehil.analysis.paper_figures',
    'vmehil.run_report': 'vmehil.reports.run_report',
    'vmehil.session': 'vmehil.rig_setup.session',
    'vmehil.system': 'vmehil.rig_setup.system',
    'vmehil.units': 'vmehil.unit_controllers',
    'vmehil.units.coordinator': 'vmehil.unit_controllers.coordinator',
    'vmehil.units.hub': 'vmehil.unit_controllers.hub',
    'vmehil.units.options': 'vmehil.unit_controllers.options',
    'vmehil.units.processes': 'vmehil.unit_controllers.processes',
    'vmehil.units.remote': 'vmehil.unit_controllers.remote',
    'vmehil.vision_options': 'vmehil.option_groups.vision_options',
}



def _alias_file(old: str) -> Path:
    """The alias's own file (not find_spec's answer: once imported, that is the moved module's)."""
    path = REPO / old.replace(".", "/")
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


MOVED_FILES = sorted(o for o in MOVED if _alias_file(o).name != "__init__.py")
MOVED_PACKAGES = sorted(o for o in MOVED if _alias_file(o).name == "__init__.py")


@pytest.mark.parametrize("old", MOVED_FILES)
def test_an_old_import_path_is_the_moved_module(old: str) -> None:
    assert importlib.import_module(old) is importlib.import_module(MOVED[old])


@pytest.mark.parametrize("old", MOVED_PACKAGES)
def test_an_old_package_path_gives_the_moved_package_names(old: str) -> None:
    new = importlib.import_module(MOVED[old])
    alias = importlib.import_module(old)
    names = [n for n in vars(new) if not n.startswith("__")]
    assert all(getattr(alias, n) is getattr(new, n) for n in names)


@pytest.mark.parametrize("old", MOVED_FILES)
def test_an_old_path_under_python_m_runs_the_moved_module_as_main(old: str, monkeypatch) -> None:
    ran = []
    monkeypatch.setattr(runpy, "run_module", lambda name, **kw: ran.append((name, kw)))
    origin = str(_alias_file(old))
    exec(compile(Path(origin).read_text(encoding="utf-8"), origin, "exec"), {"__name__": "__main__"})
    assert ran == [(MOVED[old], {"run_name": "__main__", "alter_sys": True})]


def test_python_m_on_an_old_path_exits_cleanly() -> None:
    old = MOVED_FILES[0]
    out = subprocess.run([sys.executable, "-m", old], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert (out.returncode, out.stderr) == (0, "")


def test_the_fault_matrix_and_the_fingerprint_still_run_under_python_m() -> None:
    for module in ("vmehil.fault_matrix", "tests.emulators.lockstep_fingerprint"):
        spec = importlib.util.find_spec(module)
        assert spec is not None and spec.origin is not None
        assert 'if __name__ == "__main__"' in Path(spec.origin).read_text(encoding="utf-8")
