"""One exception root per package: every exception class of ``hal``, ``emulators``, ``servo`` and
``vmehil`` (outside the tests) derives from its package's root — ``HalError``, ``EmulatorError``,
``ServoError``, ``VmehilError`` — so the command line catches four classes, not thirty.

Exempt by kind, not by name: warning categories (``warnings.warn`` takes them, nobody raises them)
and ``BaseException``s that are deliberately not ``Exception``s (a signal, like
``KeyboardInterrupt``: ``servo.interrupts.Terminated``), which no ``except Exception`` may swallow.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
from pathlib import Path

import pytest

from emulators.errors import EmulatorError
from hal.errors import HalError
from servo.errors import ServoError
from vmehil.errors import VmehilError

ROOTS: dict[str, type[Exception]] = {"hal": HalError, "emulators": EmulatorError, "servo": ServoError,
                                     "vmehil": VmehilError}
TREE = Path(__file__).resolve().parent.parent


def _modules(package: str) -> list[str]:
    pkg = importlib.import_module(package)
    names = [package]
    for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{package}."):
        if info.name.rsplit(".", 1)[-1] != "__main__":  # importing it would run the command line
            names.append(info.name)
    return sorted(names)


def _exception_classes(package: str) -> list[type[BaseException]]:
    found = []
    for name in _modules(package):
        module = importlib.import_module(name)
        for obj in vars(module).values():
            if isinstance(obj, type) and issubclass(obj, BaseException) and obj.__module__ == name:
                found.append(obj)
    return found


def _exempt(cls: type[BaseException]) -> bool:
    return issubclass(cls, Warning) or not issubclass(cls, Exception)


@pytest.mark.parametrize("package", sorted(ROOTS))
def test_every_exception_class_of_a_package_derives_from_its_root(package: str) -> None:
    root = ROOTS[package]
    classes = _exception_classes(package)
    outside = sorted(f"{c.__module__}.{c.__qualname__}" for c in classes
                     if not _exempt(c) and not issubclass(c, root))
    assert outside == [], f"not beneath {root.__name__}: {outside}"
    assert root in classes  # the root is found by the walk, so the walk sees the package's classes


@pytest.mark.parametrize("package", sorted(ROOTS))
def test_the_walk_sees_every_class_statement_of_the_package(package: str) -> None:
    # a class defined in a function or under a branch the import did not take escapes the walk
    # above; count the class statements (AST, top level of each module) against what it found
    seen = {(c.__module__, c.__qualname__) for c in _exception_classes(package)}
    for path in sorted((TREE / package).rglob("*.py")):
        if path.name == "__main__.py":
            continue
        module = ".".join(path.relative_to(TREE).with_suffix("").parts).removesuffix(".__init__")
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ClassDef) and any(
                    (isinstance(b, ast.Name) and (b.id.endswith(("Error", "Exception", "Fault", "Refused",
                                                                  "Interrupted", "Abort"))))
                    for b in node.bases):
                assert (module, node.name) in seen, f"{module}.{node.name} is not reached by the walk"


def test_a_builtin_kind_is_kept_beside_the_root() -> None:
    # callers that catch ValueError / KeyError / RuntimeError keep working
    from emulators.faults import UnknownFaultError
    from emulators.plant_link import PlantLinkError
    from hal.config import ConfigError
    from servo.control.errors import GainRejected

    assert issubclass(ConfigError, ValueError) and issubclass(GainRejected, ValueError)
    assert issubclass(UnknownFaultError, KeyError) and issubclass(PlantLinkError, RuntimeError)
