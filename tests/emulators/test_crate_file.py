"""Crate files: building a crate from TOML, and errors that name file, key and expectation."""

from __future__ import annotations

from pathlib import Path

import pytest

from emulators.crate_file import load_crate
from emulators.presets import resolve_rig
from hal.config import ConfigError
from hal.vme import Width


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "crate.toml"
    p.write_text(text)
    return p


GOOD = """
[crate]
name = "t"
[[crate.board]]
type = "ram"
name = "m"
space = "A24"
base = 0x400000
size = 256
"""


def test_crate_file_builds_boards(tmp_path: Path) -> None:
    c = load_crate(_write(tmp_path, GOOD))
    c.write(0x400010, 0xCAFE, space="A24", width=Width.D16)
    assert c.read(0x400010, space="A24", width=Width.D16) == 0xCAFE
    assert c.describe()[0]["name"] == "m"


@pytest.mark.parametrize(
    "mutation,key,expected",
    [
        (lambda s: s.replace('type = "ram"', 'type = "nope"'), "crate.board[0].type", "a board type"),
        (lambda s: s.replace('space = "A24"', 'space = "A20"'), "crate.board[0].space", "A16, A24 or A32"),
        (lambda s: s.replace("base = 0x400000", 'base = "x"'), "crate.board[0].base", "an integer"),
        (lambda s: s.replace("size = 256", "size = 256\nsise = 3"), "crate.board[0].sise", "a known key"),
        (lambda s: s.replace("size = 256", ""), "crate.board[0].size", "a value"),
        (lambda s: s + GOOD.split("[crate]")[1].replace('name = "t"', ""), "crate.board[1].base", "a free window"),
        (lambda s: s.replace("[crate]", "[crate\n"), "", "valid TOML"),  # the file, no key
    ],
)
def test_bad_crate_file_names_file_key_and_expectation(tmp_path: Path, mutation, key, expected) -> None:
    p = _write(tmp_path, mutation(GOOD))
    with pytest.raises(ConfigError) as ei:
        load_crate(p)
    msg = str(ei.value)
    assert str(p) in msg and key in msg and expected in msg, msg


def test_missing_crate_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="does not exist"):
        resolve_rig(tmp_path / "missing.toml")
    with pytest.raises(FileNotFoundError, match="presets: .*jpl-arm"):
        resolve_rig("no-such-rig")


def test_default_rig_crate_loads() -> None:
    c = load_crate(resolve_rig(None))
    assert c.boards
