"""Read a board's register table out of its documentation (docs/boards/<board>.md), the spec.

The doc is written by hand like a datasheet; its register table is a Markdown table whose header
names at least these columns (any order, more columns allowed)::

    | offset | register | width | access | reset | bits |

- ``offset``: hex byte offset from the board base (``0x02``);
- ``width``: the natural width, then any other widths the board accepts there (``D16``,
  ``D16, D8``);
- ``access``: ``RO``, ``WO``, ``RW`` or ``RW1C``;
- ``reset``: the value after power-up/reset, hex (``0x0000``), or ``—`` where a register has
  none (a write-only strobe);
- ``bits``: the fields, ``<br>``-separated, each ``[msb:lsb] NAME — text`` or ``[bit] NAME — text``
  (empty for a plain data register).

:func:`doc_registers` reads every such table in a doc; :func:`doc_rows` reads the rows of any other
table of the doc by its column names (a gain table, worked conversion examples);
:func:`map_differences` lists how a
``hal.vme.RegisterMap`` (the driver's, or the emulator's own) differs from it. The doc is the
spec: the two maps are each checked against it, never against each other.

No tests here; doc-check tests import it as ``tests.support.board_spec``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from hal.vme.registers import RegisterMap

DOCS = Path(__file__).resolve().parents[2] / "docs" / "boards"
REQUIRED = ("offset", "register", "width", "access", "reset", "bits")
_FIELD = re.compile(r"^\[(?P<msb>\d+)(?::(?P<lsb>\d+))?\]\s+(?P<name>[A-Za-z_][A-Za-z0-9_]*)")


@dataclass(frozen=True)
class DocRegister:
    """One register as the doc states it. ``fields``: name → (lsb, width in bits)."""

    name: str
    offset: int
    width: str
    also: tuple[str, ...]
    access: str
    reset: int | None
    fields: dict[str, tuple[int, int]] = field(default_factory=dict)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def doc_registers(doc: str | Path, *, table: int | None = None) -> dict[str, DocRegister]:
    """The registers of the doc's register tables (all of them, or only the ``table``-th, from 0).

    ``doc``: a path, or a board name (``"adc"`` → docs/boards/adc.md). Raises ``ValueError``
    naming the line for a row it cannot read, so a doc typo fails loudly rather than silently
    dropping a register.
    """
    path = Path(doc) if isinstance(doc, Path) or "/" in str(doc) else DOCS / f"{doc}.md"
    lines = path.read_text().splitlines()
    out: dict[str, DocRegister] = {}
    n_table = -1
    i = 0
    while i < len(lines):
        head = _cells(lines[i]) if lines[i].lstrip().startswith("|") else []
        cols = [c.lower() for c in head]
        if not all(k in cols for k in REQUIRED):
            i += 1
            continue
        n_table += 1
        i += 2  # the header and the |---| line
        while i < len(lines) and lines[i].lstrip().startswith("|"):
            if table is None or table == n_table:
                row = dict(zip(cols, _cells(lines[i]), strict=False))
                try:
                    reg = _register(row)
                except (ValueError, KeyError) as e:
                    raise ValueError(f"{path}:{i + 1}: {e}") from None
                if reg.name in out:
                    raise ValueError(f"{path}:{i + 1}: register {reg.name} stated twice")
                out[reg.name] = reg
            i += 1
    if not out:
        raise ValueError(f"{path}: no register table with the columns {', '.join(REQUIRED)}")
    return out


def doc_rows(doc: str | Path, *columns: str) -> list[dict[str, str]]:
    """The rows (column name, lower case → cell text) of every table of the doc whose header
    names all ``columns`` (case-insensitive). Raises ``ValueError`` when there is none, so a
    renamed column fails loudly rather than leaving a check with nothing to check."""
    path = Path(doc) if isinstance(doc, Path) or "/" in str(doc) else DOCS / f"{doc}.md"
    want = [c.lower() for c in columns]
    lines = path.read_text().splitlines()
    rows: list[dict[str, str]] = []
    found = False
    i = 0
    while i < len(lines):
        cols = [c.lower() for c in _cells(lines[i])] if lines[i].lstrip().startswith("|") else []
        if not cols or not all(k in cols for k in want):
            i += 1
            continue
        found = True
        i += 2  # the header and the |---| line
        while i < len(lines) and lines[i].lstrip().startswith("|"):
            rows.append(dict(zip(cols, _cells(lines[i]), strict=False)))
            i += 1
    if not found:
        raise ValueError(f"{path}: no table with the columns {', '.join(columns)}")
    return rows


def _register(row: dict[str, str]) -> DocRegister:
    widths = [w.strip() for w in row["width"].replace("/", ",").split(",") if w.strip()]
    for w in widths:
        if w not in ("D8", "D16", "D32"):
            raise ValueError(f"width {w!r}")
    access = row["access"].strip()
    if access not in ("RO", "WO", "RW", "RW1C"):
        raise ValueError(f"access {access!r}")
    reset_text = row["reset"].strip()
    reset = None if reset_text in ("—", "-", "") else int(reset_text, 16)
    fields: dict[str, tuple[int, int]] = {}
    bits = row["bits"].strip()
    for item in filter(None, (b.strip() for b in bits.split("<br>"))):
        m = _FIELD.match(item)
        if m is None:
            raise ValueError(f"bit field {item!r} (expected '[msb:lsb] NAME — text')")
        msb = int(m["msb"])
        lsb = int(m["lsb"]) if m["lsb"] is not None else msb
        fields[m["name"]] = (lsb, msb - lsb + 1)
    return DocRegister(row["register"].strip().strip("`"), int(row["offset"], 16), widths[0], tuple(widths[1:]),
                       access, reset, fields)


def map_differences(regmap: RegisterMap, doc: dict[str, DocRegister], *, who: str = "map") -> list[str]:
    """Every way ``regmap`` differs from the doc's registers (empty: they agree)."""
    diffs: list[str] = []
    declared = {r.name: r for r in regmap.registers}
    for name in sorted(set(doc) - set(declared)):
        diffs.append(f"{who}: register {name} is in the doc but not declared")
    for name in sorted(set(declared) - set(doc)):
        diffs.append(f"{who}: register {name} is declared but not in the doc")
    for name in sorted(set(doc) & set(declared)):
        d, r = doc[name], declared[name]
        if r.offset != d.offset:
            diffs.append(f"{who}: {name} at 0x{r.offset:X}, doc 0x{d.offset:X}")
        if r.width.name != d.width:
            diffs.append(f"{who}: {name} width {r.width.name}, doc {d.width}")
        if sorted(w.name for w in r.also) != sorted(d.also):
            diffs.append(f"{who}: {name} also {[w.name for w in r.also]}, doc {list(d.also)}")
        if r.access.value != d.access:
            diffs.append(f"{who}: {name} access {r.access.value}, doc {d.access}")
        if d.reset is not None and r.reset != d.reset:
            diffs.append(f"{who}: {name} reset 0x{r.reset:X}, doc 0x{d.reset:X}")
        got = {f.name: (f.lsb, f.width) for f in r.fields}
        if got != d.fields:
            diffs.append(f"{who}: {name} fields {got}, doc {d.fields}")
    return diffs
