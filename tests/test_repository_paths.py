"""Every repository path named in the docs and in the code's docstrings and comments exists.

A path is a run of ``[\\w./-]`` starting with one of the tree's top-level folders (``tests/``,
``docs/``, ``hal/``, …) and ending in a file name with an extension (folders are not checked); a
``::name`` after a test file, named outside tests/, must name a function or class in it. Templates
(``docs/boards/<board>.md``, ``calibration/<rig>.toml``, globs) are not paths and are skipped.
CHANGELOG.md is history (a path named there was right when it was written) and is not read.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
TOP = ("tests", "docs", "hal", "emulators", "servo", "vmehil", "benchmarks", ".ci")
_PATH = re.compile(r"(?<![\w./-])((?:" + "|".join(re.escape(t) for t in TOP)
                   + r")/[\w./-]*[\w/])(::[A-Za-z_]\w*)?")


def _sources() -> list[Path]:
    files = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    for top in ("hal", "emulators", "servo", "vmehil", "tests", "benchmarks"):
        files += sorted(p for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)
    files += [ROOT / "Makefile", ROOT / "pyproject.toml"]
    return files


def _named_paths(text: str) -> list[tuple[str, str | None]]:
    out = []
    for m in _PATH.finditer(text):
        path, member = m.group(1).rstrip("."), m.group(2)
        if any(c in text[m.end(1):m.end(1) + 1] for c in "<*{") or path.endswith("/"):
            continue  # a template or a glob (docs/boards/<board>.md), or a folder
        if not re.search(r"\.\w+$", path):
            continue  # not a file (a module path with dots is caught by the extension test)
        out.append((path, member[2:] if member else None))
    return out


def test_every_repository_path_named_in_docs_and_docstrings_exists() -> None:
    missing = []
    for src in _sources():
        if src.resolve() == Path(__file__).resolve():
            continue
        text = src.read_text(errors="replace")
        # tests name made-up node ids as arguments (tests/test_pair.py): only their files count
        in_tests = src.is_relative_to(ROOT / "tests")
        for path, member in _named_paths(text):
            target = ROOT / path
            if not target.exists():
                missing.append(f"{src.relative_to(ROOT)}: {path}")
            elif member is not None and not in_tests and target.is_file() and not re.search(
                    rf"^\s*(?:async\s+)?(?:def|class)\s+{re.escape(member)}\b", target.read_text(), re.M):
                missing.append(f"{src.relative_to(ROOT)}: {path}::{member}")
    assert not missing, "named but not in the tree:\n" + "\n".join(missing)
