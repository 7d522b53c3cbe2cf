"""The console's line protocol: request parsing, line assembly, reply formatting (with fuzzing)."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vmehil.console.protocol import (
    ERROR_CODES,
    MAX_LINE,
    Arg,
    ConsoleError,
    LineAssembler,
    is_reply_line,
    kv,
    parse_line,
    parse_reply_line,
)


@pytest.mark.parametrize("line, name, args", [
    ("status", "status", ()),
    ("  move [10, -20.5 ,3] speed=0.5 ", "move", ((None, (10.0, -20.5, 3.0)), ("speed", 0.5))),
    ("move_rel 1,2,3", "move_rel", ((None, (1.0, 2.0, 3.0)),)),
    ("gains j1 kp=120 kv=5e1", "gains", ((None, "j1"), ("kp", 120), ("kv", 50.0))),
    ('echo "hello \\"world\\"" ', "echo", ((None, 'hello "world"'),)),
    ("run motions/demo-1.toml", "run", ((None, "motions/demo-1.toml"),)),
    ('load file="a b.cmd"', "load", (("file", "a b.cmd"),)),
    ("log 5", "log", ((None, 5),)),
    ("mode nan", "mode", ((None, "nan"),)),  # not a number: a word
])
def test_parse_good_lines(line, name, args):
    req = parse_line(line)
    assert req is not None and req.name == name
    assert tuple((a.key, a.value) for a in req.args) == args


@pytest.mark.parametrize("line", ["", "   ", "# a comment", "\t# x"])
def test_blank_and_comment_lines_are_nothing(line):
    assert parse_line(line) is None


@pytest.mark.parametrize("line, col, fragment", [
    ("x=3", 1, "command name"),
    ("3 status", 1, "command name"),
    ("move speed=1 2", 14, "positional argument after"),
    ('echo "abc', 6, "unterminated string"),
    ('echo "a"b', 6, "nothing after the closing quote"),
    ("move [1,2", 6, "unterminated vector"),
    ("move [1,x]", 6, "not a number"),
    ("move [1]]", 6, "vector"),
    ("gains kp=", 7, "needs a value"),
    ('echo ab"c"', 6, "quote inside a word"),
])
def test_syntax_errors_name_the_column(line, col, fragment):
    with pytest.raises(ConsoleError) as ei:
        parse_line(line)
    assert ei.value.code == "SYNTAX"
    assert f"column {col}" in ei.value.message and fragment in ei.value.message


def test_assembler_handles_terminators_editing_and_garbage():
    la = LineAssembler(8)
    events = la.feed(b"abc\r\nhello world!\nok\x7fk\n\x00x\n\xff\xfe\nab\x03cd\r\x15\nxy\x08z\n")
    assert [(e.kind, e.text) for e in events] == [
        ("line", "abc"), ("long", ""), ("line", "ok"), ("binary", ""), ("binary", ""), ("line", "cd"),
        ("line", "xz")]
    # an over-long line is discarded to its terminator only; the assembler stays bounded
    assert [e.kind for e in la.feed(b"x" * 10_000)] == []
    assert len(la._buf) <= 8
    assert [(e.kind, e.text) for e in la.feed(b"\nok\n")] == [("long", ""), ("line", "ok")]


def test_assembler_deletes_whole_utf8_characters():
    la = LineAssembler()
    assert [e.text for e in la.feed("a°".encode() + b"\x7f" + b"b\n")] == ["ab"]


def test_replies_round_trip_through_parse_reply_line():
    line = kv("DATA", "joint", joint="j 1", pos_deg=1.25, missing=float("nan"), v=(1.0, 2.5), on=True,
              text='say "hi"=x')
    prefix, words, pairs = parse_reply_line(line)
    assert prefix == "DATA" and words == ["joint"]
    assert pairs == {"joint": "j 1", "pos_deg": "1.25", "missing": "nan", "v": "[1,2.5]", "on": "1",
                     "text": 'say "hi"=x'}
    assert is_reply_line(line) and is_reply_line("OK status") and not is_reply_line("status")


def test_console_error_codes_are_checked():
    with pytest.raises(ValueError):
        ConsoleError("NOPE", "x")
    assert ConsoleError("ARGS", "a\nb").reply_line() == "ERR ARGS a b"


# ---- fuzzing ----------------------------------------------------------------------------------------------
text_lines = st.text(st.characters(blacklist_categories=("Cs",)), max_size=200)
token_lines = st.lists(st.sampled_from(['move', 'gains', 'x=1', '"', '[', ']', ',', '1', '-2.5e3', 'kp=', '"a b"',
                                        '[1, 2]', ' ', '#', 'j1', '=', '\\', 'nan', '1,2,']), max_size=12).map("".join)


@settings(max_examples=400, deadline=None)
@given(st.one_of(text_lines, token_lines))
def test_fuzzed_lines_parse_or_raise_a_typed_error(line):
    try:
        req = parse_line(line)
    except ConsoleError as e:
        assert e.code in ERROR_CODES
        return
    if req is not None:
        assert req.name and all(isinstance(a, Arg) for a in req.args)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=8))
def test_fuzzed_bytes_never_break_the_assembler(chunks):
    la = LineAssembler(64)
    for c in chunks:
        for ev in la.feed(c):
            assert ev.kind in ("line", "long", "binary")
            if ev.kind == "line":
                assert len(ev.text.encode()) <= 64 and "\n" not in ev.text and "\r" not in ev.text
        assert len(la._buf) <= 64


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.from_regex(r"[a-z_][a-z0-9_]{0,8}", fullmatch=True),
                       st.one_of(st.text(max_size=20), st.integers(), st.floats(allow_nan=False, allow_infinity=False)),
                       max_size=5))
def test_fuzzed_reply_values_round_trip(pairs):
    line = kv("DATA", "x", **pairs)
    assert "\n" not in line and "\r" not in line
    _, _, got = parse_reply_line(line)
    assert set(got) == set(pairs)
    for k, v in pairs.items():
        if isinstance(v, str) and v.isprintable():
            assert got[k] == v


def test_max_line_is_documented_size():
    assert MAX_LINE == 512
