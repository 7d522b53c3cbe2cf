"""Atomic writes: the old file or the new one, never a mix; the previous one kept on request."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from vmehil.files import write_atomic, write_json


def test_write_atomic_replaces_and_keeps_previous(tmp_path: Path) -> None:
    p = tmp_path / "cal.toml"
    write_atomic(p, "a = 1\n")
    write_atomic(p, "a = 2\n", keep_previous=True)
    assert p.read_text() == "a = 2\n"
    assert (tmp_path / "cal.toml.prev").read_text() == "a = 1\n"
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_failed_write_leaves_old_file_and_no_temp(tmp_path: Path, monkeypatch) -> None:
    p = tmp_path / "x.json"
    write_atomic(p, "old")

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", boom)
    with pytest.raises(OSError):
        write_atomic(p, "new")
    assert p.read_text() == "old"
    assert not [f for f in os.listdir(tmp_path) if f.endswith(".tmp")]


def test_write_json_writes_null_for_nan_and_inf(tmp_path: Path) -> None:
    p = write_json(tmp_path / "r.json", {"gm": float("inf"), "x": [float("nan"), 1.0]})
    assert json.loads(p.read_text()) == {"gm": None, "x": [None, 1.0]}
