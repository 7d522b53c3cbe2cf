"""Console lines, fuzzed through the console's assembler, parser and dispatcher (vmehil/console):
raw bytes and request lines built from the real command names, parameter names and value
shapes. Property: nothing escapes ``feed``, every reply line carries a protocol prefix, and no
command ends in ``ERR INTERNAL`` (an exception the console had to catch); the loop keeps
ticking. Each example gets a fresh loop and console. Commands that read files (``run``,
``load``) or start procedures (``calibrate``) are not built here (tests/vmehil/console covers them)."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from tests.fuzz.harness import refused
from tests.support.fakes import make_loop, tick
from vmehil.console.commands import ATOMS
from vmehil.console.protocol import REPLY_PREFIXES
from vmehil.console.server import Console

NOT_BUILT = {"run", "load", "calibrate"}
NAMES = sorted(set(ATOMS) - NOT_BUILT)
PARAMS = sorted({p.name for a in ATOMS.values() for p in a.params})

number_text = st.one_of(
    st.integers(-10**6, 10**6).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["0", "-0", "1e308", "1e309", "-1e999", "nan", "inf", "-inf", "1e-320", "+", "-", ".", "1e",
                     "99999999999999999999999999", "0x10", "1_000"]),
)
word = st.text(st.characters(min_codepoint=33, max_codepoint=126, exclude_characters='"#[]=,'), min_size=1,
               max_size=12)
joint = st.sampled_from(["j1", "j2", "j3", "all", "0", "1", "2", "3", "-1"])
vector = st.lists(number_text, max_size=5).map(lambda xs: "[" + ", ".join(xs) + "]") | \
    st.lists(number_text, min_size=2, max_size=4).map(",".join)
quoted = st.text(max_size=20).map(lambda s: '"' + s.replace("\n", " ").replace("\r", " ") + '"')
value = st.one_of(number_text, word, joint, vector, quoted, st.sampled_from(["[", "]", '"', "[1,,2]", "=", "==1"]))
arg = st.one_of(value, st.tuples(st.sampled_from(PARAMS) | word, value).map(lambda kv: f"{kv[0]}={kv[1]}"))
line = st.tuples(st.sampled_from(NAMES) | word, st.lists(arg, max_size=5)).map(
    lambda t: " ".join([t[0], *t[1]]))


def _console():
    loop = make_loop(2)
    console = Console(loop, None)
    out: list[str] = []
    console.taps.append(out.append)
    return loop, console, out


def _drain(loop, console) -> None:
    for _ in range(50):
        tick(loop, console)
        if console.pending() == 0 and not console.executor.active:
            break


def _check(loop, out: list[str]) -> None:
    for reply in out:
        assert reply.split(" ", 1)[0] in REPLY_PREFIXES, reply
        assert not reply.startswith("ERR INTERNAL") and " INTERNAL " not in reply, reply
        if reply.startswith("ERR "):
            refused("ERR " + reply.split(" ", 2)[1])
    assert loop.fault is None or loop.fault.cause not in ("exception", "interrupted"), loop.fault


@given(lines=st.lists(line, min_size=1, max_size=6), endings=st.sampled_from(["\n", "\r", "\r\n"]))
def test_built_request_lines_only_produce_typed_replies(lines: list[str], endings: str) -> None:
    loop, console, out = _console()
    k0 = loop.tick_count
    for text in lines:
        console.feed((text + endings).encode("utf-8", errors="surrogatepass"))
    _drain(loop, console)
    _check(loop, out)
    assert loop.tick_count > k0


@given(st.lists(st.one_of(st.binary(max_size=80),
                          st.sampled_from([b"status\n", b"gains j1 kp=\n", b"move 1,2\r", b"move [\n",
                                           b"echo \"x\n", b"\x7f\x7f\n", b"log 999\n", b"hop 1\n", b"\x03\x15\n",
                                           b"x" * 600 + b"\n"])),
                max_size=10))
def test_raw_bytes_through_the_console_only_produce_typed_replies(chunks: list[bytes]) -> None:
    loop, console, out = _console()
    for c in chunks:
        console.feed(c)
    _drain(loop, console)
    _check(loop, out)
