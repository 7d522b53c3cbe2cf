"""Mutations of a valid TOML document for the loader harnesses: one value replaced by garbage,
a key or table deleted, an unknown key added, or the text itself corrupted."""

from __future__ import annotations

import copy
from typing import Any

import tomli_w
from hypothesis import strategies as st

Path_ = tuple[Any, ...]

scalar = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True), st.integers(-2**63, 2**63 - 1), st.integers(-10**30, 10**30),
    st.sampled_from([0, -1, 1, 0.0, -0.0, 1e-300, 1e300, 2**31, 2**53 + 1]),
    st.text(max_size=12), st.sampled_from(["", "adc0:0", "dac0:99", "pio0:PB9", "A16", "A64", "adc0", "pid", "j1",
                                           "0x6000", "nan", "inf"]),
    st.booleans(), st.dates(), st.datetimes(), st.times(),
)
garbage = st.one_of(scalar, st.lists(scalar, max_size=4), st.dictionaries(st.text(max_size=6), scalar, max_size=3),
                    st.lists(st.dictionaries(st.sampled_from(["name", "type", "slot", "base"]), scalar, max_size=3),
                             max_size=2))


def leaves(doc: Any, path: Path_ = ()) -> list[Path_]:
    """Every key path (tables and values) in ``doc``."""
    out: list[Path_] = []
    items = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for k, v in items:
        out.append((*path, k))
        out += leaves(v, (*path, k))
    return out


def _parent(doc: Any, path: Path_) -> Any:
    for k in path[:-1]:
        doc = doc[k]
    return doc


@st.composite
def mutated(draw: st.DrawFn, text: str, doc: dict[str, Any]) -> bytes:
    """A mutation of ``doc`` (parsed from ``text``) as file bytes."""
    op = draw(st.sampled_from(["set", "set", "set", "delete", "add", "text"]))
    if op == "text":
        raw = text.encode()
        at = draw(st.integers(0, len(raw)))
        how = draw(st.sampled_from(["insert", "truncate", "replace"]))
        junk = draw(st.binary(min_size=1, max_size=8) | st.sampled_from([b"=", b"[", b"]]", b'"', b"\n[[joint]]\n",
                                                                           b"\xff", b"\x00", b" = nan\n"]))
        if how == "truncate":
            return raw[:at]
        if how == "replace":
            return raw[:at] + junk + raw[at + len(junk):]
        return raw[:at] + junk + raw[at:]
    new = copy.deepcopy(doc)
    paths = leaves(new)
    path = draw(st.sampled_from(paths))
    parent = _parent(new, path)
    if op == "set":
        parent[path[-1]] = draw(garbage)
    elif op == "delete":
        if isinstance(parent, list):
            parent.pop(path[-1])
        else:
            del parent[path[-1]]
    else:
        target = parent if isinstance(parent, dict) else new
        target[draw(st.text(min_size=1, max_size=10))] = draw(scalar)
    return tomli_w.dumps(new).encode()


__all__ = ["garbage", "leaves", "mutated", "scalar"]
