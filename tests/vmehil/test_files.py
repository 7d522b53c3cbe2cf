"""Atomic writes: the old file or the new one, never a mix; no temporary file left behind, even by a
killed process; the umask obeyed; the previous file kept on request, and only claimed when it existed."""

from __future__ import annotations

import json
import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from tests.support import REPO
from vmehil.writers import files
from vmehil.writers.files import (
    is_temp_file,
    remove_stale_temp_files,
    temp_path_for,
    to_json,
    write_atomic,
    write_atomic_keeping_previous,
    write_json,
)


def _temps(folder: Path) -> list[str]:
    return [f for f in os.listdir(folder) if f.endswith(".tmp")]


@pytest.fixture
def umask():
    """Set the process umask for one test (restored after it)."""
    old = os.umask(0o022)
    try:
        yield os.umask
    finally:
        os.umask(old)


def test_write_atomic_replaces_and_keeps_previous(tmp_path: Path) -> None:
    p = tmp_path / "cal.toml"
    write_atomic(p, "a = 1\n")
    done = write_atomic_keeping_previous(p, "a = 2\n")
    assert p.read_text() == "a = 2\n"
    assert done.path == p and done.previous == tmp_path / "cal.toml.prev"
    assert done.previous.read_text() == "a = 1\n"
    assert not _temps(tmp_path)


def test_previous_is_claimed_only_when_there_was_a_previous_file(tmp_path: Path) -> None:
    p = tmp_path / "cal.toml"
    first = write_atomic_keeping_previous(p, "a = 1\n")
    assert first.previous is None
    assert not (tmp_path / "cal.toml.prev").exists()
    # a stray .prev of a file since deleted is not this write's previous file
    p.unlink()
    (tmp_path / "cal.toml.prev").write_text("ancient\n")
    again = write_atomic_keeping_previous(p, "a = 2\n")
    assert again.previous is None
    assert (tmp_path / "cal.toml.prev").read_text() == "ancient\n"


def test_keeping_previous_replaces_an_older_prev(tmp_path: Path) -> None:
    p = tmp_path / "x.txt"
    for text in ("1", "2", "3"):
        write_atomic_keeping_previous(p, text)
    assert p.read_text() == "3" and (tmp_path / "x.txt.prev").read_text() == "2"
    assert not _temps(tmp_path)


def test_a_prev_linked_to_the_file_is_refreshed_without_a_leftover(tmp_path: Path) -> None:
    """A write killed between keeping ``.prev`` and its last rename leaves ``.prev`` a hard link
    of the file itself; rename(2) between two links of one file does nothing."""
    p = tmp_path / "cal.toml"
    write_atomic(p, "a\n")
    os.link(p, tmp_path / "cal.toml.prev")
    done = write_atomic_keeping_previous(p, "b\n")
    assert p.read_text() == "b\n" and done.previous is not None and done.previous.read_text() == "a\n"
    assert not _temps(tmp_path)


def test_failed_write_leaves_old_file_and_no_temp(tmp_path: Path, monkeypatch) -> None:
    p = tmp_path / "x.json"
    write_atomic(p, "old")
    real_replace = os.replace

    def boom(src, dst):
        if Path(dst) == p:
            raise OSError("disk full")
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        write_atomic(p, "new")
    with pytest.raises(OSError):
        write_atomic_keeping_previous(p, "new")  # the snapshot for .prev is not left behind either
    assert p.read_text() == "old"
    assert not _temps(tmp_path)


def test_interrupted_write_removes_its_temporary_file(tmp_path: Path, monkeypatch) -> None:
    p = tmp_path / "x.csv"

    def interrupt(fd):
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "fsync", interrupt)
    with pytest.raises(KeyboardInterrupt):
        write_atomic(p, "a,b\n")
    assert not p.exists() and not _temps(tmp_path)


def test_temporary_names_are_recognisable_and_hidden(tmp_path: Path) -> None:
    t = temp_path_for(tmp_path / "sweep.json")
    assert t.parent == tmp_path and t.name.startswith(".sweep.json.") and t.name.endswith(".tmp")
    assert is_temp_file(t.name) and str(os.getpid()) in t.name
    assert not is_temp_file(".sweep.json.tmp") and not is_temp_file("sweep.json")


def test_written_files_follow_the_umask(tmp_path: Path, umask) -> None:
    p = tmp_path / "report.json"
    umask(0o022)
    write_json(p, {"a": 1})
    assert stat.S_IMODE(p.stat().st_mode) == 0o644
    umask(0o077)
    write_atomic(p, "x")  # a replaced file takes the mode of the new write
    assert stat.S_IMODE(p.stat().st_mode) == 0o600
    umask(0o002)
    prev = write_atomic_keeping_previous(p, "y").previous
    assert stat.S_IMODE(p.stat().st_mode) == 0o664
    assert prev is not None and stat.S_IMODE(prev.stat().st_mode) == 0o600  # the old file, as it was


def test_a_secret_is_never_more_open_than_asked(tmp_path: Path, umask) -> None:
    umask(0o022)
    p = write_atomic(tmp_path / "k", "secret", mode=0o600)
    assert stat.S_IMODE(p.stat().st_mode) == 0o600


def kill_mid_write(target: Path, code: str) -> Path:
    """Run ``code`` in a child process whose ``os.replace`` onto ``target`` stops after the
    temporary file is written and fsynced; SIGKILL it there. Returns the temporary file it left.
    (Shared with the calibration store's test.)"""
    script = textwrap.dedent(f"""
        import os, sys, time
        real_replace = os.replace
        def slow_replace(src, dst):          # the test hook: stop between write and rename
            if str(dst) == {str(target)!r}:  # (not the rename that keeps a .prev)
                print("WRITTEN", src, flush=True)
                time.sleep(60)
            real_replace(src, dst)
        os.replace = slow_replace
    """) + textwrap.dedent(code)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, cwd=REPO,
                            env={**os.environ, "PYTHONPATH": str(REPO)})
    try:
        line = proc.stdout.readline()
        assert line.startswith("WRITTEN"), line
        tmp_file = Path(line.split()[1])
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(timeout=30) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stdout.close()
    return tmp_file


def test_killed_mid_write_keeps_the_old_file_and_the_next_write_removes_the_orphan(tmp_path: Path) -> None:
    p = tmp_path / "sweep.csv"
    write_atomic(p, "old\n")
    orphan = kill_mid_write(p, f"from vmehil.writers import files; files.write_atomic({str(p)!r}, 'new\\n')")
    assert p.read_text() == "old\n"
    assert orphan.exists() and orphan.read_text() == "new\n" and is_temp_file(orphan.name)
    write_atomic(p, "newer\n")
    assert p.read_text() == "newer\n"
    assert not _temps(tmp_path)


def test_orphans_of_any_target_in_the_folder_are_removed(tmp_path: Path) -> None:
    p = tmp_path / "cal.toml"
    write_atomic(p, "a\n")
    orphan = kill_mid_write(p, f"from vmehil.writers import files; files.write_atomic_keeping_previous({str(p)!r}, 'b\\n')")  # noqa: E501  (a moved module's longer path; apply_moves.py)
    assert orphan.exists()
    write_json(tmp_path / "other.json", {})  # another file of the same folder
    assert not _temps(tmp_path)
    assert p.read_text() == "a\n"


def test_temporary_files_of_live_processes_or_other_hosts_are_left_alone(tmp_path: Path) -> None:
    live = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        mine = temp_path_for(tmp_path / "a.json")
        theirs = mine.with_name(mine.name.replace(f"-{os.getpid()}-", f"-{live.pid}-"))
        other_host = mine.with_name(mine.name.replace(files._HOST, "0" * 8 if files._HOST != "0" * 8 else "1" * 8))
        for t in (mine, theirs, other_host):
            t.write_text("being written")
        assert remove_stale_temp_files(tmp_path) == []
        assert mine.exists() and theirs.exists() and other_host.exists()
    finally:
        live.kill()
        live.wait()
    assert remove_stale_temp_files(tmp_path) == [theirs]  # its process has ended


def test_write_json_writes_null_for_nan_and_inf(tmp_path: Path) -> None:
    p = write_json(tmp_path / "r.json", {"gm": float("inf"), "x": [float("nan"), 1.0]})
    assert json.loads(p.read_text()) == {"written_by": "vmehil", "gm": None, "x": [None, 1.0]}


def test_to_json_takes_numpy_and_complex_values() -> None:
    obj = {"a": np.float32(0.5), "b": np.array([1.0, np.nan]), "c": np.int64(3), "d": np.bool_(True),
           "e": complex(1.0, -2.0), "f": np.float64(-np.inf), np.int64(7): "numpy key", (1, 2): "tuple key"}
    assert json.loads(to_json(obj)) == {"a": 0.5, "b": [1.0, None], "c": 3, "d": True, "e": {"re": 1.0, "im": -2.0},
                                        "f": None, "7": "numpy key", "(1, 2)": "tuple key"}
    assert "NaN" not in to_json([float("nan")]) and to_json({}).endswith("\n")


def test_save_figure_writes_each_format(tmp_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    out = files.save_figure(fig, tmp_path / "plot", ("png", "svg"))
    plt.close(fig)
    assert out == [tmp_path / "plot.png", tmp_path / "plot.svg"]
    assert out[0].read_bytes().startswith(b"\x89PNG") and b"<svg" in out[1].read_bytes()
    assert not _temps(tmp_path)
