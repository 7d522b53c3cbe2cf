"""Output paths are checked before a command does any work, and never overwrite what is not ours.

"Ours" is a file vmehil wrote (JSON with ``"written_by": "vmehil"``, which
:func:`vmehil.writers.files.write_json` adds to every object it writes) or a directory vmehil created
(it holds the marker file :data:`MARKER`). ``--force`` (anywhere on the command line) overrides.
Checked at start, so that ``--report`` naming an existing file no longer dies with a traceback
after the whole run.
"""

from __future__ import annotations

import argparse
import json
import os
from dataclasses import dataclass
from pathlib import Path

from vmehil.errors import VmehilError
from vmehil.writers.files import WRITTEN_BY

MARKER = ".vmehil-output"  #: the file that marks a directory as vmehil's (report, sweep output)

#: the attributes of a parsed command line that name output files and output directories
FILE_OPTIONS = {"json": "--json", "json_path": "--json", "can_log": "--can-log", "trace_out": "--trace-out"}
#: what a binary or text output of ours carries near its start or its end (a trace file: vmehil.scope)
MARK = b"written_by=vmehil"
DIR_OPTIONS = {"report": "--report", "out": "--out", "resume": "--resume"}


class OutputPathError(VmehilError, ValueError):
    """An output path that cannot or must not be written; the message names the flag."""


def _is_ours(p: Path) -> bool:
    try:
        with p.open("rb") as f:
            head = f.read(1 << 20)
            if MARK in head[:4096]:
                return True
            size = f.seek(0, os.SEEK_END)
            f.seek(max(0, size - (1 << 16)))
            if MARK in f.read():  # a footer's metadata (Parquet, MCAP)
                return True
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


@dataclass(frozen=True)
class OutputPaths:
    """The output files and directories a command line names, each with its flag."""

    files: tuple[tuple[str, Path], ...] = ()
    dirs: tuple[tuple[str, Path], ...] = ()

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> OutputPaths:
        """Every output option of a parsed command line (calibrate's ``--out`` is its calibration
        file, kept with a ``.prev`` by the store, and is not an output directory)."""
        def named(options: dict[str, str], skip: str | None = None) -> tuple[tuple[str, Path], ...]:
            out = []
            for attr, flag in options.items():
                value = None if attr == skip else getattr(args, attr, None)
                for v in value if isinstance(value, list | tuple) else [value]:  # a repeatable flag
                    if isinstance(v, str | Path):
                        out.append((flag, Path(v)))
            return tuple(out)

        return cls(files=named(FILE_OPTIONS),
                   dirs=named(DIR_OPTIONS, skip="out" if getattr(args, "command", None) == "calibrate" else None))


def mark_output_dirs(outputs: OutputPaths) -> None:
    """After a command: mark the output directories it wrote again (made and marked at start by
    :func:`check_outputs`; a command may have replaced their contents)."""
    for _flag, p in outputs.dirs:
        _mark(p)


def _inside_any(p: Path, dirs: tuple[Path, ...]) -> bool:
    rp = p.resolve()
    return any(rp == d.resolve() or d.resolve() in rp.parents for d in dirs)


def check_outputs(outputs: OutputPaths, *, force: bool = False) -> list[Path]:
    """Check every output option of a command line before it runs. Once all are accepted, the
    folder of an output file that lies in a new output directory is created. Returns the output
    directories made here (:func:`remove_unused` takes them back after a refused command)."""
    for flag, p in outputs.dirs:
        check_output_dir(p, flag, force=force)
    made_here = tuple(p for _flag, p in outputs.dirs if not p.exists())
    files = [check_output_file(p, flag, force=force, made_here=made_here) for flag, p in outputs.files]
    # every check passed (nothing is created for a refused command): the output directories are
    # made and marked first, so that a command killed before its end (SIGKILL) leaves them ours
    for _flag, p in outputs.dirs:
        _mark(p, create=True)
    for f in files:
        if not f.parent.is_dir():
            f.parent.mkdir(parents=True, exist_ok=True)
    return [p for p in made_here if p.is_dir()]


def remove_unused(made: list[Path]) -> None:
    """Take back the output directories :func:`check_outputs` made for a command that was then
    refused (bad input): each that holds nothing but the marker. A refused command leaves nothing."""
    for p in made:
        try:
            if {q.name for q in p.iterdir()} <= {MARKER}:
                (p / MARKER).unlink(missing_ok=True)
                p.rmdir()
        except OSError:
            pass


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
