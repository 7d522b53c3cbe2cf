"""The walls between the packages hold at import time: no module imports itself back through a
circle of imports, and the controller runs without loading any emulator.

The package-level contracts (hal → nothing of ours, emulators/servo → hal, nothing → vmehil, no
cycles between sibling packages) are import-linter's, in pyproject.toml; ``make test`` runs them.
This test refuses the cycles acyclic_siblings cannot see: between a package's ``__init__`` and its
own modules, or through TYPE_CHECKING imports and imports inside functions (grimp counts all).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import grimp
import pytest

OURS = ("hal", "emulators", "servo", "vmehil")


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    found: list[list[str]] = []
    for root in sorted(graph.modules):
        if root in index:
            continue
        work = [(root, iter(sorted(graph.find_modules_directly_imported_by(root))))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(graph.find_modules_directly_imported_by(child)))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    m = stack.pop()
                    on_stack.discard(m)
                    component.append(m)
                    if m == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def _describe(graph: grimp.ImportGraph, component: list[str]) -> str:
    lines = [" ↔ ".join(component)]
    for importer in component:
        for imported in sorted(graph.find_modules_directly_imported_by(importer)):
            if imported in component:
                for d in graph.get_import_details(importer=importer, imported=imported):
                    lines.append(f"    {importer}:{d['line_number']}: {d['line_contents']}")
    return "\n".join(lines)


def test_cycle_finder_names_a_circle():
    g = grimp.ImportGraph()
    for a, b in [("p.a", "p.b"), ("p.b", "p.c"), ("p.c", "p.a"), ("p.c", "p.d"), ("p.d", "p.d2")]:
        g.add_import(importer=a, imported=b, line_number=1, line_contents=f"import {b}")
    assert _cycles(g) == [["p.a", "p.b", "p.c"]]
    assert "p.c:1: import p.a" in _describe(g, ["p.a", "p.b", "p.c"])


def test_no_module_of_ours_imports_itself_back():
    graph = grimp.build_graph(*OURS, cache_dir=None)
    cycles = _cycles(graph)
    assert not cycles, "import cycles:\n" + "\n".join(_describe(graph, c) for c in cycles)


def test_the_controller_runs_without_loading_an_emulator():
    code = "import servo.runner, sys; print([m for m in sys.modules if m.startswith('emulators')])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120)
    assert out.stdout.strip() == "[]"


# Runs pytest on tests/servo in a fresh interpreter whose import system refuses every vmehil
# module (a meta-path finder ahead of the others): the controller's own tests need only servo,
# hal and, for the rig presets, emulators.
_WITHOUT_VMEHIL = """
import sys

class RefuseVmehil:
    def find_spec(self, name, path=None, target=None):
        if name == "vmehil" or name.startswith("vmehil."):
            raise ModuleNotFoundError(f"No module named {name!r} (refused: tests/servo runs without vmehil)",
                                      name=name)
        return None

sys.meta_path.insert(0, RefuseVmehil())
import pytest
code = pytest.main(["-q", "-p", "no:cacheprovider", "-x", "tests/servo"])
print("vmehil loaded:", [m for m in sys.modules if m == "vmehil" or m.startswith("vmehil.")])
sys.exit(int(code))
"""


@pytest.mark.slow  # runs tests/servo once more (~20 s)
def test_the_servo_tests_run_with_vmehil_absent():
    root = Path(__file__).resolve().parent.parent
    out = subprocess.run([sys.executable, "-c", _WITHOUT_VMEHIL], capture_output=True, text=True, timeout=600,
                         cwd=root)
    assert out.returncode == 0, out.stdout[-4000:] + out.stderr[-2000:]
    assert "vmehil loaded: []" in out.stdout
    assert " passed" in out.stdout


def test_the_vmehil_refusing_finder_refuses():
    code = _WITHOUT_VMEHIL.split("import pytest")[0] + "import vmehil.cli\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode != 0 and "refused: tests/servo runs without vmehil" in out.stderr
