"""Every file vmehil writes goes through here: atomic text/bytes, JSON and figure writes.

A write goes to a temporary file in the target's folder (so the rename cannot cross file
systems), is fsynced, renamed over the target (atomic on POSIX) and the folder fsynced (so the
rename itself survives a power cut). A reader sees the old file or the new one, never a mix.

Temporary files are named ``.<target>.vmehil-<host>-<pid>-<random>.tmp``: hidden, recognisable
and tied to the process that writes them. A write that fails (an exception, a KeyboardInterrupt)
removes its own; a process killed outright (SIGKILL, power cut) cannot, so every write first
removes those of dead processes of this host in its folder — the next write after a kill leaves
no orphan. Another host's or a live process's temporary file is never touched.

Files are created with mode ``0o666`` filtered by the umask, like ``open(path, "w")`` (not the
0600 of :func:`tempfile.mkstemp`); pass ``mode=0o600`` for secrets. A replaced file gets the new
mode: it is a new file, not an edit of the old one.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import math
import os
import re
import secrets
import shutil
import socket
from dataclasses import dataclass
from pathlib import Path
from typing import Any

#: Permission bits asked for at creation; the umask takes its bits off, as for any new file.
DEFAULT_MODE = 0o666
PREVIOUS_SUFFIX = ".prev"

# Hostname hashed to a fixed-size token: a shared (NFS) folder may hold another host's live
# temporary files, whose PIDs mean nothing here.
_HOST = hashlib.sha1(socket.gethostname().encode("utf-8", "replace")).hexdigest()[:8]
_TEMP_RE = re.compile(r"^\..+\.vmehil-(?P<host>[0-9a-f]{8})-(?P<pid>\d+)-[0-9a-f]{8}\.tmp$")


@dataclass(frozen=True)
class Replaced:
    """What :func:`write_atomic_keeping_previous` did: the file written, and where its previous
    content was kept (``None`` when there was no previous file — nothing was kept)."""

    path: Path
    previous: Path | None


def temp_path_for(target: Path) -> Path:
    """A fresh temporary name beside ``target`` (see the module docstring for the pattern)."""
    return target.with_name(f".{target.name}.vmehil-{_HOST}-{os.getpid()}-{secrets.token_hex(4)}.tmp")


def is_temp_file(name: str) -> bool:
    """True for the name of a temporary file of these writes (any process, any host)."""
    return _TEMP_RE.match(name) is not None


def remove_stale_temp_files(folder: str | Path) -> list[Path]:
    """Remove the temporary files left in ``folder`` by dead processes of this host; returns them."""
    removed: list[Path] = []
    try:
        names = os.listdir(folder)
    except OSError:
        return removed
    for name in names:
        m = _TEMP_RE.match(name)
        if m is None or m["host"] != _HOST:
            continue
        pid = int(m["pid"])
        if pid == os.getpid() or _pid_alive(pid):
            continue
        p = Path(folder) / name
        with contextlib.suppress(FileNotFoundError):
            p.unlink()
            removed.append(p)
    return removed


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, belongs to someone else
        return True
    return True


def _open_temp(target: Path, mode: int) -> tuple[int, Path]:
    """Create a new temporary file beside ``target`` (O_EXCL: never someone else's)."""
    while True:
        tmp = temp_path_for(target)
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), mode), tmp
        except FileExistsError:  # 32 random bits collided: draw again
            continue


def _fsync_folder(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:  # e.g. a platform that cannot open folders: the rename is still atomic
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems refuse fsync on a folder; the file itself is synced
        pass
    finally:
        os.close(fd)


def _write(path: str | Path, data: bytes | str, *, mode: int, keep_previous: bool) -> Replaced:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    remove_stale_temp_files(p.parent)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    fd, tmp = _open_temp(p, mode)
    kept: Path | None = None
    prev_tmp: Path | None = None
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(raw)
            f.flush()
            os.fsync(f.fileno())
        if keep_previous:
            prev_tmp = _snapshot(p)
            if prev_tmp is not None:
                kept = p.with_name(p.name + PREVIOUS_SUFFIX)
                os.replace(prev_tmp, kept)
                # rename(2) does nothing when both names are links to one file (a .prev left
                # linked to the file by a write killed before its last rename): drop the extra link
                with contextlib.suppress(FileNotFoundError):
                    prev_tmp.unlink()
                prev_tmp = None
        os.replace(tmp, p)
    except BaseException:
        for t in (tmp, prev_tmp):
            if t is not None:
                with contextlib.suppress(FileNotFoundError):
                    t.unlink()
        raise
    _fsync_folder(p.parent)
    return Replaced(p, kept)


def _snapshot(p: Path) -> Path | None:
    """The current content of ``p`` under a temporary name (hard link, else a copy); ``None``
    when there is no ``p``. Renamed to ``.prev`` afterwards, so an old ``.prev`` is replaced in
    one step and a crash never leaves none."""
    snap = temp_path_for(p)
    try:
        os.link(p, snap)
    except FileNotFoundError:
        return None
    except OSError:  # no hard links on this file system
        try:
            shutil.copy2(p, snap)
        except FileNotFoundError:
            return None
        except BaseException:
            with contextlib.suppress(FileNotFoundError):
                snap.unlink()
            raise
    return snap


def write_atomic(path: str | Path, data: bytes | str, *, mode: int = DEFAULT_MODE) -> Path:
    """Write ``data`` (``str`` as UTF-8) to ``path`` atomically; returns the path."""
    return _write(path, data, mode=mode, keep_previous=False).path


def write_atomic_keeping_previous(path: str | Path, data: bytes | str, *, mode: int = DEFAULT_MODE) -> Replaced:
    """:func:`write_atomic`, keeping the file it replaces as ``<name>.prev`` (when there is one)."""
    return _write(path, data, mode=mode, keep_previous=True)


def to_json(obj: Any, *, indent: int | None = 2) -> str:
    """Indented JSON text (``indent=None``: one line), never the non-standard ``NaN``/``Infinity``:
    non-finite floats are ``null``, numpy scalars and arrays are numbers and lists, complex
    numbers ``{"re", "im"}``."""
    return json.dumps(_jsonable(obj), indent=indent, allow_nan=False) + "\n"


#: the mark vmehil leaves in the JSON objects it writes (``vmehil.writers.output_paths`` knows its own files by it)
WRITTEN_BY = "vmehil"


def write_json(path: str | Path, obj: Any) -> Path:
    """Atomically write ``obj`` as :func:`to_json` text; an object gets ``"written_by": "vmehil"``
    first, so that a later run may overwrite it (``vmehil.writers.output_paths``)."""
    if isinstance(obj, dict) and "written_by" not in obj:
        obj = {"written_by": WRITTEN_BY, **obj}
    return write_atomic(path, to_json(obj))


def _jsonable(obj: Any) -> Any:
    if isinstance(obj, float):  # numpy's float64 too
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, complex):
        return {"re": _jsonable(obj.real), "im": _jsonable(obj.imag)}
    if isinstance(obj, dict):
        return {_json_key(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "tolist") and not isinstance(obj, str | bytes):  # numpy, without importing it here
        return _jsonable(obj.tolist())
    return obj


def _json_key(k: Any) -> Any:
    if hasattr(k, "tolist") and not isinstance(k, str):
        k = k.tolist()
    return k if k is None or isinstance(k, str | int | float) else str(k)


def save_figure(fig: Any, path: str | Path, formats: tuple[str, ...] = ("png",), *, dpi: int = 110,
                tight: bool = True) -> list[Path]:
    """Save a matplotlib figure atomically once per format, as ``<path>.<format>`` (``path``
    without suffix); returns the files in the order of ``formats``. ``tight=False``: the figure's
    own box (no second draw to measure a tight one)."""
    out = []
    for fmt in formats:
        buf = io.BytesIO()
        fig.savefig(buf, format=fmt, dpi=dpi, bbox_inches="tight" if tight else None)
        out.append(write_atomic(Path(f"{path}.{fmt}"), buf.getvalue()))
    return out
