"""Compound command files: parsing with typed parameters, load-time checks with positions, and
execution (sequences, async blocks, sync) at tick boundaries. Fuzzed files never crash the parser."""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.support.fakes import make_loop, tick
from vmehil.console.commands import Session
from vmehil.console.compound import (
    AsyncBlock,
    CompoundError,
    Executor,
    Sync,
    load_compound_file,
    parse_compound,
    tokenize,
)

GOOD = """
# the paper's Fig. 8, in this rig's atoms
command turn_right() = async { # async means do the following as a sequence:
    move_joint(1, -90.0, 1.0);   # first joint to -90 degrees
    move_rel([0, 6.75], 0.5);    # second joint by 6.75 degrees at half speed
    move_joint(1, 0.0);          # back
}

command wave(float amp, int times, string label, vector home) = {
    echo(label);
    move_joint("j2", amp, speed=0.5);
    move_joint(2, -amp);
    async { pause(0.5); echo("half a second later"); }
    sync;
    move(home);
    gains("all", kp=100, kv=50.0);
    mode("auto", 1);
};

command both(float a) = {
    wave(a, 2, "w", [0, 0]);
    move([a, -a]);
}
"""


def test_good_file_parses_with_typed_parameters_and_structure():
    lib = parse_compound(GOOD, "good.cmd", n_joints=2, names=["j1", "j2"])
    assert list(lib) == ["turn_right", "wave", "both"]
    assert lib["turn_right"].is_async and not lib["wave"].is_async
    assert [(p.name, p.type) for p in lib["wave"].params] == [
        ("amp", "float"), ("times", "int"), ("label", "string"), ("home", "vector")]
    body = lib["wave"].body
    assert isinstance(body[3], AsyncBlock) and isinstance(body[4], Sync)
    assert lib["wave"].usage() == "wave amp:float times:int label:string home:vector"
    assert str(lib["both"].pos) == "good.cmd:20:9"


def test_file_loads_from_disk_and_checks_motion_files_at_load(tmp_path):
    (tmp_path / "m.toml").write_text('[[move]]\ntargets_deg = [1, 2]\n')
    f = tmp_path / "c.cmd"
    f.write_text('command go() = { run("m.toml"); }\n')
    lib = load_compound_file(f, n_joints=2, names=["j1", "j2"])
    assert lib["go"].body[0].prepared["motion"].moves
    f.write_text('command go() = {\n  run("missing.toml");\n}\n')
    with pytest.raises(CompoundError, match=r"c\.cmd:2:3: .*missing\.toml"):
        load_compound_file(f, n_joints=2, names=["j1", "j2"])


BAD = [
    ("command x() = { nothing(); }", 1, 17, "unknown command 'nothing'"),
    ("command x() = { move([1, 2, 3]); }", 1, 17, "needs 2 values"),
    ("command x(float a) = { move_joint(1, a, \"fast\"); }", 1, 24, "speed must be a float, got a string"),
    ("command x() = { move_joint(7, 1.0); }", 1, 17, "joint 7 does not exist"),
    ("command x() = { move_joint(\"elbow\", 1.0); }", 1, 17, "no joint 'elbow'"),
    ("command x() = { echo(hello); }", 1, 22, "unknown name 'hello'"),
    ("command x() = {\n  status();\n  move_rel([1, 1])\n}", 4, 1, "expected ';'"),
    ("command x() = {\n  status();", 2, 12, "missing '}'"),
    ("command x(real a) = { }", 1, 11, "unknown type 'real'"),
    ("command x(int a, int a) = { }", 1, 22, "declared twice"),
    ("command move() = { }", 1, 9, "atomic command"),
    ("command x() = { }\ncommand x() = { }", 2, 9, "defined twice"),
    ("command x() = { y(); }\ncommand y() = { }", 1, 17, "defined before they are used"),
    ("command x() = { help(); }", 1, 17, "console line only"),
    ("command x() = { echo(\"a); }", 1, 22, "unterminated string"),
    ("command x() = { pause(1.0.0); }", 1, 23, "not a number"),
    ("command x() = { echo(\"a\") ; } @", 1, 31, "unexpected character"),
    ("command x(string s) = { pause(-s); }", 1, 32, "numeric parameter"),
    ("command x() = { move([1, \"a\"]); }", 1, 26, "vector elements must be numbers"),
    ("command x(string f) = { run(f); }", 1, 25, "literal file name"),
    ("command x() = { log(count=1, count=2); }", 1, 17, "given twice"),
    ("command x() = { log(1, 2); }", 1, 17, "at most 1 argument"),
    ("command x() = { stay(now=1); }", 1, 17, "no argument 'now'"),
    ("move(1);", 1, 1, "expected 'command"),
    ("command x() = { command y() = {} }", 1, 17, "cannot be defined inside"),
]


@pytest.mark.parametrize("text, line, col, fragment", BAD)
def test_bad_files_name_file_line_and_column(text, line, col, fragment):
    with pytest.raises(CompoundError) as ei:
        parse_compound(text, "bad.cmd", n_joints=2, names=["j1", "j2"])
    e = ei.value
    assert (e.file, e.line, e.col) == ("bad.cmd", line, col), str(e)
    assert fragment in e.message
    assert str(e).startswith(f"bad.cmd:{line}:{col}: ")


def test_not_utf8_file_is_an_error_with_position(tmp_path):
    f = tmp_path / "x.cmd"
    f.write_bytes(b"command x() = {\n  echo(\"\xff\");\n}\n")
    with pytest.raises(CompoundError, match=r"x\.cmd:2:9: .*UTF-8"):
        load_compound_file(f)


# ---- execution ---------------------------------------------------------------------------------------------
def _exec(text: str, n: int = 2):
    loop = make_loop(n)
    events: list[str] = []
    s = Session(loop)
    ex = Executor(s, events.append)
    s.executor = ex
    s.library = parse_compound(text, "run.cmd", n_joints=n, names=list(loop.names))
    return loop, ex, events


def _run(loop, ex, max_ticks=2000):
    for _ in range(max_ticks):
        if not ex.active:
            return
        ex.step()
        tick(loop)
    raise AssertionError("compound command did not finish")


def test_sequence_waits_for_each_motion_to_end():
    loop, ex, events = _exec("command seq() = { move_joint(1, 5.0); move_joint(1, 0.0); echo(\"end\"); }")
    ex.start(ex.session.library["seq"], {})
    _run(loop, ex)
    starts = [t for t, src, msg in loop.log if msg.startswith("move j1")]
    d1 = float(next(m for _, _, m in loop.log if m.startswith("move j1 to 5")).split("(")[1].split(" s")[0])
    assert len(starts) == 2
    # the second move started when the first one had ended (one tick of hand-over at most)
    assert starts[1] - starts[0] == pytest.approx(d1, abs=2.5 * loop.period_s)
    assert events[-1].startswith("EVT done 1 seq")
    assert "EVT out 1 INFO end" in events
    assert math.degrees(loop.sequencer.current.end[0]) == pytest.approx(0.0, abs=1e-9)


def test_async_block_runs_beside_the_sequence_and_sync_waits_for_it():
    loop, ex, events = _exec('command par() = { async { pause(0.2); echo("a"); } echo("b"); sync; echo("c"); }')
    ex.start(ex.session.library["par"], {})
    _run(loop, ex)
    outs = [e.split()[-1] for e in events if e.startswith("EVT out")]
    assert outs == ["b", "a", "c"]


def test_parameters_flow_into_calls_and_nested_commands():
    loop, ex, _events = _exec('command go(float a, vector v) = { move(v); move_joint(2, -a); }\n'
                             'command outer(float x) = { go(x, [x, 0]); echo("ok"); }')
    ex.start(ex.session.library["outer"], {"x": 4.0})
    _run(loop, ex)
    assert [round(math.degrees(x), 9) for x in loop.sequencer.current.end] == [4.0, -4.0]


def test_concurrent_motions_fail_the_invocation_with_the_statement_position():
    loop, ex, events = _exec("command clash() = {\n  async { move_joint(1, 5.0); }\n  move_joint(2, 5.0);\n}")
    ex.start(ex.session.library["clash"], {})
    _run(loop, ex)
    failed = [e for e in events if e.startswith("EVT failed")]
    # the main strand runs first in a tick, so the async block's move is the one refused
    assert failed and "STATE" in failed[0] and "run.cmd:2:11:" in failed[0]
    assert not ex.active


def test_a_fault_while_waiting_for_a_motion_fails_the_invocation():
    loop, ex, events = _exec("command slow() = { move_joint(1, 20.0, 0.1); echo(\"never\"); }")
    ex.start(ex.session.library["slow"], {})
    ex.step()
    tick(loop, n=5)
    loop.safe_stop("test", "injected")
    _run(loop, ex)
    assert any(e.startswith("EVT failed 1 slow STATE") and "test" in e for e in events)
    assert "EVT out 1 INFO never" not in events


def test_stop_statement_cancels_everything():
    loop, ex, events = _exec('command halt() = { async { pause(5.0); echo("late"); } stop(); echo("x"); }')
    ex.start(ex.session.library["halt"], {})
    _run(loop, ex)
    assert loop.fault is not None and loop.fault.cause == "operator_stop"
    assert any(e.startswith("EVT cancelled 1 halt") for e in events)
    assert not any("late" in e or e.endswith(" x") for e in events)


def test_statements_per_tick_are_bounded():
    body = " ".join('echo("x");' for _ in range(100))
    loop, ex, events = _exec(f"command many() = {{ {body} }}")
    ex.start(ex.session.library["many"], {})
    ex.step()
    assert ex.statements_run == ex.statements_per_tick
    _run(loop, ex)
    assert sum(e.startswith("EVT out") for e in events) == 100


# ---- fuzzing ----------------------------------------------------------------------------------------------
pieces = st.sampled_from(["command", " ", "x", "(", ")", "=", "{", "}", ";", "async", "sync", "float a", ",",
                          "move", "move_joint", "echo", '"s"', "[1, 2]", "1.5", "-", "a", "#c\n", "\n", "int",
                          "vector v", "pause", "run", "wave", "@", '"', "1e999"])


@settings(max_examples=400, deadline=None)
@given(st.one_of(st.lists(pieces, max_size=40).map("".join), st.text(max_size=200)))
def test_fuzzed_files_parse_or_raise_compound_error(text):
    try:
        lib = parse_compound(text, "fuzz.cmd", n_joints=2, names=["j1", "j2"])
    except CompoundError as e:
        assert e.file == "fuzz.cmd" and e.line >= 1 and e.col >= 1
        return
    for d in lib.values():
        assert d.name


def test_tokenizer_positions():
    toks = tokenize('command a(\n  float b) = { }', "t")
    assert [(t.text, t.pos.line, t.pos.col) for t in toks[:6]] == [
        ("command", 1, 1), ("a", 1, 9), ("(", 1, 10), ("float", 2, 3), ("b", 2, 9), (")", 2, 10)]
