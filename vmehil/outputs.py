"""Output paths are checked before a command does any work, and never overwrite what is not ours.

"Ours" is a file vmehil wrote (JSON with ``"written_by": "vmehil"``, which
:func:`vmehil.files.write_json` adds to every object it writes) or a directory vmehil created
(it holds the marker file :data:`MARKER`). ``--force`` (anywhere on the command line) overrides.
Checked at start, so that ``--report`` naming an existing file no longer dies with a traceback
after the whole run.
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from vmehil.files import WRITTEN_BY

MARKER = ".vmehil-output"  #: the file that marks a directory as vmehil's (report, sweep output)

#: the attributes of a parsed command line that name output files and output directories
FILE_OPTIONS = {"json": "--json", "json_path": "--json", "can_log": "--can-log"}
DIR_OPTIONS = {"report": "--report", "out": "--out", "resume": "--resume"}


class OutputPathError(ValueError):
    """An output path that cannot or must not be written; the message names the flag."""


def _is_ours(p: Path) -> bool:
    try:
        with p.open("rb") as f:
            head = f.read(1 << 20)
        data = json.loads(head)
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and data.get("written_by") == WRITTEN_BY


def check_output_file(path: str | Path, flag: str, *, force: bool = False,
                      made_here: tuple[Path, ...] = ()) -> Path:
    """Check an output file before the command runs. Its folder must exist, or be one of
    ``made_here`` (or lie inside one): the output directories this command creates, as
    ``make run``'s ``--report reports/run --json reports/run/run.json`` does."""
    p = Path(path)
    if p.is_dir():
        raise OutputPathError(f"{flag} {p}: is a directory; give a file name")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        if _inside_any(parent, made_here):
            return p
        raise OutputPathError(f"{flag} {p}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK):
        raise OutputPathError(f"{flag} {p}: the folder {parent} is not writable")
    if p.exists() and not force and not _is_ours(p):
        raise OutputPathError(f"{flag} {p}: the file exists and was not written by vmehil; "
                              "choose another name or add --force to overwrite it")
    return p


def check_output_dir(path: str | Path, flag: str, *, force: bool = False) -> Path:
    """Check ``path`` before the command runs; nothing is created (a refused command leaves no
    trace). Once every output is accepted, :func:`check_outputs` creates it and marks it as
    vmehil's before the command writes anything: a command killed half-way leaves a directory
    the next run (or ``tune sweep --resume``) accepts as its own."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise OutputPathError(f"{flag} {p}: exists and is not a directory; give a directory name")
    if p.is_dir() and not (p / MARKER).exists() and any(p.iterdir()) and not force:
        raise OutputPathError(f"{flag} {p}: the directory is not empty and was not made by vmehil; "
                              "choose another one or add --force to write into it")
    return p


def _dir_options(args: argparse.Namespace) -> list[tuple[str, Path]]:
    out = []
    for attr, flag in DIR_OPTIONS.items():
        if attr == "out" and getattr(args, "command", None) == "calibrate":
            continue
        value = getattr(args, attr, None)
        if isinstance(value, str | Path):
            out.append((flag, Path(value)))
    return out


def mark_output_dirs(args: argparse.Namespace) -> None:
    """After a command: mark the output directories it wrote again (made and marked at start by
    :func:`check_outputs`; a command may have replaced their contents)."""
    for _flag, p in _dir_options(args):
        _mark(p)


def _inside_any(p: Path, dirs: tuple[Path, ...]) -> bool:
    rp = p.resolve()
    return any(rp == d.resolve() or d.resolve() in rp.parents for d in dirs)


def check_outputs(args: argparse.Namespace, *, force: bool = False) -> None:
    """Check every output option of a parsed command line (calibrate's ``--out`` is its
    calibration file, kept with a ``.prev`` by the store, and is not checked here). Once all are
    accepted, the folder of an output file that lies in a new output directory is created."""
    dirs = _dir_options(args)
    for flag, p in dirs:
        check_output_dir(p, flag, force=force)
    made_here = tuple(p for _flag, p in dirs if not p.exists())
    files = []
    for attr, flag in FILE_OPTIONS.items():
        value = getattr(args, attr, None)
        if isinstance(value, str | Path):
            files.append(check_output_file(value, flag, force=force, made_here=made_here))
    # every check passed (nothing is created for a refused command): the output directories are
    # made and marked first, so that a command killed before its end (SIGKILL) leaves them ours
    for _flag, p in dirs:
        _mark(p, create=True)
    for f in files:
        if not f.parent.is_dir():
            f.parent.mkdir(parents=True, exist_ok=True)


def _mark(p: Path, *, create: bool = False) -> None:
    """Put the marker in directory ``p`` (made first with ``create``); a failure here is left to
    the command's own writes to report."""
    try:
        if create:
            p.mkdir(parents=True, exist_ok=True)
        if p.is_dir():
            (p / MARKER).touch()
    except OSError:
        pass
