"""The commands without the extras installed (each in a fresh interpreter where the extras'
modules cannot be imported): the default `vmehil run` needs none; a command or option that needs
one refuses in one line that names the extra to install, exit status 2, before doing anything."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from tests.support import REPO
from vmehil.commands import EXTRA_MODULES

EVERY_EXTRA = sorted({m for modules in EXTRA_MODULES.values() for m in modules})

# `vmehil ARGS` with BLOCKED (comma-separated top-level modules) not importable, as if not installed.
WITHOUT = """
import sys
blocked = set(sys.argv[1].split(","))

class NotInstalled:
    def find_spec(self, name, path=None, target=None):
        if name.partition(".")[0] in blocked:
            raise ModuleNotFoundError(f"No module named {name!r}", name=name)
        return None

sys.meta_path.insert(0, NotInstalled())
from vmehil.cli import main
sys.exit(main(sys.argv[2:]))
"""


def vmehil_without(modules: list[str], *argv: str, cwd) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", WITHOUT, ",".join(modules), *argv], cwd=cwd, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "PYTHONPATH": str(REPO)})


@pytest.mark.slow  # over 5 s: make test runs it, make test-fast leaves it out
def test_the_default_run_needs_no_extra(tmp_path) -> None:
    r = vmehil_without(EVERY_EXTRA, "run", "--duration", "0.2", "--quiet", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "j1" in r.stdout  # the per-joint table


@pytest.mark.parametrize(("argv", "line"), [
    (["tune", "bode"], "vmehil tune needs the 'tune' extra: pip install 'vmehil[tune]'"),
    (["tune", "step"], "vmehil tune needs the 'tune' extra: pip install 'vmehil[tune]'"),
    (["calibrate", "friction", "--auto"],
     "vmehil calibrate friction needs the 'tune' extra: pip install 'vmehil[tune]'"),
    (["calibrate", "dac", "--auto", "--report", "rep"],
     "vmehil calibrate --report needs the 'plots' extra: pip install 'vmehil[plots]'"),
    (["run", "--report", "rep"], "vmehil run --report needs the 'plots' extra: pip install 'vmehil[plots]'"),
    (["run", "--mavlink", "udpin:127.0.0.1:14550"],
     "vmehil run --mavlink needs the 'mavlink' extra: pip install 'vmehil[mavlink]'"),
    (["run", "--console", "loop://"], "vmehil run --console needs the 'console' extra: pip install 'vmehil[console]'"),
    (["console", "--port", "loop://"],
     "vmehil console --console loop:// needs the 'console' extra: pip install 'vmehil[console]'"),
    (["run", "--trace", "*"], "vmehil run --trace needs the 'trace' extra: pip install 'vmehil[trace]'"),
    (["coordinate", "--trace", "*"], "vmehil coordinate --trace needs the 'trace' extra: pip install 'vmehil[trace]'"),
    (["trace", "show", "t.mcap"], "vmehil trace show needs the 'plots' extra: pip install 'vmehil[plots]'"),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_a_command_that_needs_a_missing_extra_says_which_in_one_line(tmp_path, argv, line) -> None:
    r = vmehil_without(EVERY_EXTRA, *argv, cwd=tmp_path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.splitlines() == [line]
    assert not list(tmp_path.iterdir())  # refused before doing anything


def test_the_console_on_a_pty_needs_no_extra(tmp_path) -> None:
    r = vmehil_without(EVERY_EXTRA, "console", "--port", f"pty:{tmp_path / 'console'}", "--lockstep",
                       "--duration", "0.1", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "console: pty" in r.stderr


def test_the_calibrate_help_lists_the_procedure_whose_extra_is_missing(tmp_path) -> None:
    r = vmehil_without(["scipy"], "calibrate", "--help", cwd=tmp_path)
    assert r.returncode == 0
    assert "friction" in r.stdout  # listed; running it without the extra says what to install


@pytest.mark.slow
def test_the_dask_engine_without_dask_says_which_extra(tmp_path) -> None:
    r = vmehil_without(["dask", "distributed"], "tune", "sweep", "--engine", "dask", "--quiet", cwd=tmp_path)
    assert r.returncode == 2, (r.stdout, r.stderr)
    assert r.stderr.splitlines()[-1] == ("vmehil tune sweep --engine dask needs the 'dask' extra: "
                                         "pip install 'vmehil[dask]'")
    assert not list(tmp_path.iterdir())  # refused before writing anything
