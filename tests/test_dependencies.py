"""What vmehil needs installed: the drivers (hal) and the controller (servo) need numpy and
nothing else; pyproject's extras bring exactly the modules the commands check for, and ``all``
is every extra. (How each command behaves without its extra: tests/vmehil/commands/test_extras.py.)"""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from importlib.metadata import packages_distributions

from tests.support import REPO
from vmehil.commands import EXTRA_MODULES

# Imports every module of hal and servo in a fresh interpreter and prints the top-level names of
# the modules that came with them from outside the standard library (those with a file: an
# extension's internal modules, such as Cython's, have none).
IMPORT_ALL = """
import importlib, pkgutil, sys
before = set(sys.modules)
for top in ("hal", "servo"):
    pkg = importlib.import_module(top)
    for info in pkgutil.walk_packages(pkg.__path__, top + "."):
        importlib.import_module(info.name)
added = {name.partition(".")[0] for name in set(sys.modules) - before}
print(" ".join(sorted(n for n in added if n not in sys.stdlib_module_names and n not in ("hal", "servo")
                      and getattr(sys.modules.get(n), "__file__", None))))
"""


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def _names(requirements: list[str]) -> set[str]:
    """Normalized distribution names of requirement strings (``"SciPy>=1.11"`` → ``"scipy"``)."""
    return {re.sub(r"[-_.]+", "-", re.match(r"[A-Za-z0-9][A-Za-z0-9._-]*", r).group()).lower() for r in requirements}


def test_hal_and_servo_load_no_third_party_module_but_numpy() -> None:
    out = subprocess.run([sys.executable, "-c", IMPORT_ALL], cwd=REPO, capture_output=True, text=True, timeout=120,
                         check=True).stdout.split()
    assert set(out) <= {"numpy"}, out


def test_the_walk_imports_every_module_of_hal_and_servo() -> None:
    """The check above sees every module: a package walk finds each .py file under hal/ and servo/."""
    files = {p.relative_to(REPO).with_suffix("").as_posix().replace("/", ".").removesuffix(".__init__")
             for top in ("hal", "servo") for p in (REPO / top).rglob("*.py")}
    walked = subprocess.run(
        [sys.executable, "-c", "import pkgutil, hal, servo\n"
         "for p in (hal, servo):\n"
         "    print(p.__name__)\n"
         "    for i in pkgutil.walk_packages(p.__path__, p.__name__ + '.'): print(i.name)"],
        cwd=REPO, capture_output=True, text=True, timeout=120, check=True).stdout.split()
    assert files == set(walked)


def test_each_extra_brings_the_modules_its_commands_check_for() -> None:
    extras = _pyproject()["project"]["optional-dependencies"]
    providers = packages_distributions()
    for extra, modules in EXTRA_MODULES.items():
        provided = {d for m in modules for d in providers.get(m, [])}
        assert _names(extras[extra]) == _names(sorted(provided)), \
            f"pyproject's '{extra}' extra and vmehil.commands.EXTRA_MODULES disagree"


def test_all_is_every_extra_but_the_tests() -> None:
    extras = _pyproject()["project"]["optional-dependencies"]
    others = set(extras) - {"all", "test"}
    assert others == set(EXTRA_MODULES)
    assert _names(extras["all"]) == set().union(*(_names(extras[e]) for e in others))


def test_the_plant_analysis_module_loads_without_scipy() -> None:
    # scipy is an extra (tune): the plant tests and the friction CLI import emulators.plant.friction_metrics,
    # and only the dead-band cycle's root search needs scipy, so only that imports it
    code = ("import sys, emulators.plant.friction_metrics as a\n"
            "print('scipy' in sys.modules)\n"
            "a.deadband_limit_cycle\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120,
                         check=True).stdout.split()
    assert out == ["False"]
