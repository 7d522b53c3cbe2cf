"""Compound commands: user-defined commands built from the atomic ones, as in (DM)².

The file language (one or more definitions; ``#`` comments)::

    # Wave joint 2, then go home while joint 1 moves at the same time
    command wave(float amp, float speed) = {
        move_joint(2, amp, speed);          # a statement waits until its motion has ended
        move_joint(2, -amp, speed);
    }

    command home_both(vector home) = async {   # top-level async: the body is a sequence that runs
        async {                                # beside the console (optional keyword, as in the paper)
            move_joint("j1", 0.0);             # a nested async block runs concurrently with what follows
        }
        echo("j1 is homing");
        sync;                                  # wait for the async blocks started above
        wave(5.0, 0.5);                        # previously defined compound commands can be called
        move(home, speed=0.5);
    }

Grammar::

    file       := { definition }
    definition := "command" NAME "(" [ param { "," param } ] ")" "=" [ "async" ] block [ ";" ]
    param      := TYPE NAME                  TYPE := string | int | float | vector
    block      := "{" { statement } "}"
    statement  := "async" block [ ";" ] | "sync" ";" | call ";"
    call       := NAME "(" [ arg { "," arg } ] ")"
    arg        := [ NAME "=" ] expr
    expr       := [ "-" ] NUMBER | STRING | [ "-" ] NAME | "[" [ expr { "," expr } ] "]"

Everything is checked when the file is loaded — unknown commands, argument count, names and
types (a NAME in an expression is a parameter of the enclosing command, with its declared type),
vector lengths against the rig's joint count, joint names, and the motion files named by ``run``
(loaded then) — and every error is a :class:`CompoundError` naming ``file:line:column``.

Execution (:class:`Executor`) is driven at tick boundaries: each invocation is a set of strands
(sequences); a statement that starts a motion (``move``, ``run``, …) or a ``pause`` holds its
strand until it is complete; ``async { … }`` starts a new strand; ``sync`` and the end of a body
wait for the strands started in that body. Two strands commanding motions at once get a STATE
error (one trajectory generator, one owner), which fails the invocation. A runtime error, ``stop``
or ``cancel`` ends the whole invocation, reported as an ``EVT`` line with the statement's position.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Union

from hal.config import ConfigError, read_limited
from vmehil.console.commands import (
    ATOMS,
    FLOAT,
    INT,
    STRING,
    VECTOR,
    Atom,
    Param,
    Session,
    Typed,
    bind,
    check_console_file,
)
from vmehil.console.commands import prepare as prepare_atom
from vmehil.console.protocol import BUSY, FILE, INTERNAL, STATE, ConsoleError, Value, kv, one_line, type_name
from vmehil.errors import VmehilError

TYPES = (STRING, INT, FLOAT, VECTOR)
KEYWORDS = {"command", "async", "sync"}
PUNCT = set("(){}[],;=-")
MAX_FILE_BYTES = 1_000_000
MAX_DEPTH = 64


class CompoundError(VmehilError, ValueError):
    """A compound command file error at ``file:line:col``."""

    def __init__(self, file: str, line: int, col: int, message: str) -> None:
        self.file, self.line, self.col, self.message = file, line, col, message
        super().__init__(f"{file}:{line}:{col}: {message}")


@dataclass(frozen=True)
class Pos:
    file: str
    line: int
    col: int

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.col}"

    def error(self, message: str) -> CompoundError:
        return CompoundError(self.file, self.line, self.col, message)


# ---- lexer ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Token:
    kind: str  # "name", "number", "string", "punct", "eof"
    text: str
    value: Any
    pos: Pos


def tokenize(text: str, file: str = "<commands>") -> list[Token]:
    """Split ``text`` into tokens; :class:`CompoundError` on a character that starts none."""
    from vmehil.console.protocol import FLOAT_RE, INT_RE

    toks: list[Token] = []
    i, n, line, lstart = 0, len(text), 1, 0
    while i < n:
        c = text[i]
        pos = Pos(file, line, i - lstart + 1)
        if c == "\n":
            line += 1
            lstart = i + 1
            i += 1
        elif c.isspace():
            i += 1
        elif c == "#":
            while i < n and text[i] != "\n":
                i += 1
        elif c.isalpha() or c == "_":
            j = i
            while j < n and (text[j].isalnum() or text[j] == "_"):
                j += 1
            toks.append(Token("name", text[i:j], text[i:j], pos))
            i = j
        elif c.isdigit() or (c == "." and i + 1 < n and text[i + 1].isdigit()):
            j = i
            while j < n and (text[j].isalnum() or text[j] in "._" or (text[j] in "+-" and text[j - 1] in "eE")):
                j += 1
            word = text[i:j]
            if INT_RE.match(word):
                value: Any = int(word)
            elif FLOAT_RE.match(word) and math.isfinite(float(word)):
                value = float(word)
            else:
                raise pos.error(f"{word!r} is not a number")
            toks.append(Token("number", word, value, pos))
            i = j
        elif c == '"':
            j = i + 1
            buf = []
            while True:
                if j >= n or text[j] == "\n":
                    raise pos.error('unterminated string (a string is "text" on one line)')
                if text[j] == "\\" and j + 1 < n and text[j + 1] in '"\\':
                    buf.append(text[j + 1])
                    j += 2
                    continue
                if text[j] == '"':
                    break
                buf.append(text[j])
                j += 1
            s = "".join(buf)
            if not all(ch.isprintable() or ch == "\t" for ch in s):
                raise pos.error("a string may hold printable characters only")
            toks.append(Token("string", text[i: j + 1], s, pos))
            i = j + 1
        elif c in PUNCT:
            toks.append(Token("punct", c, c, pos))
            i += 1
        else:
            raise pos.error(f"unexpected character {c!r}")
    toks.append(Token("eof", "", None, Pos(file, line, n - lstart + 1)))
    return toks


# ---- syntax tree ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Literal:
    value: Value
    pos: Pos


@dataclass(frozen=True)
class ParamRef:
    name: str
    type: str
    negate: bool
    pos: Pos


@dataclass(frozen=True)
class VectorExpr:
    items: tuple[Union[Literal, ParamRef], ...]  # noqa: UP007
    pos: Pos


Expr = Union[Literal, ParamRef, VectorExpr]  # noqa: UP007


@dataclass
class Call:
    name: str
    args: tuple[tuple[str | None, Expr], ...]
    pos: Pos
    target: Any = None  # Atom or CompoundDef
    prepared: dict[str, Any] | None = None  # bound arguments prepared at load time (run: the motion)


@dataclass(frozen=True)
class AsyncBlock:
    body: tuple[Any, ...]
    pos: Pos


@dataclass(frozen=True)
class Sync:
    pos: Pos


@dataclass
class CompoundDef:
    """A user-defined command: ``name``, typed ``params``, ``body`` (statements), where it was defined."""

    name: str
    params: tuple[Param, ...]
    body: tuple[Any, ...]
    pos: Pos
    is_async: bool

    @property
    def where(self) -> str:
        return str(self.pos)

    def usage(self) -> str:
        return " ".join([self.name, *(p.usage() for p in self.params)])


class CompoundLibrary(dict):
    """Compound commands by name (insertion order = definition order)."""

    def merged(self, other: CompoundLibrary) -> CompoundLibrary:
        out = CompoundLibrary(self)
        out.update(other)
        return out


# ---- parser -----------------------------------------------------------------------------------------------
class _Parser:
    def __init__(self, tokens: list[Token], file: str, n_joints: int | None, names: list[str] | None,
                 known: CompoundLibrary, base_dir: Path | None) -> None:
        self.toks = tokens
        self.i = 0
        self.file = file
        self.n_joints = n_joints
        self.names = names
        self.lib = CompoundLibrary(known)
        self.defined_here: list[str] = []
        self.base_dir = base_dir
        self.params: dict[str, Param] = {}

    # token helpers
    @property
    def tok(self) -> Token:
        return self.toks[self.i]

    def next(self) -> Token:
        t = self.toks[self.i]
        if t.kind != "eof":
            self.i += 1
        return t

    def is_punct(self, c: str) -> bool:
        return self.tok.kind == "punct" and self.tok.text == c

    def expect_punct(self, c: str, what: str) -> Token:
        if not self.is_punct(c):
            raise self.tok.pos.error(f"expected {c!r} {what}, found {self._show(self.tok)}")
        return self.next()

    def expect_name(self, what: str) -> Token:
        if self.tok.kind != "name":
            raise self.tok.pos.error(f"expected {what}, found {self._show(self.tok)}")
        return self.next()

    @staticmethod
    def _show(t: Token) -> str:
        return "the end of the file" if t.kind == "eof" else repr(t.text)

    # grammar
    def file_(self) -> CompoundLibrary:
        while self.tok.kind != "eof":
            self.definition()
        return CompoundLibrary({k: self.lib[k] for k in self.defined_here})

    def definition(self) -> None:
        t = self.tok
        if not (t.kind == "name" and t.text == "command"):
            raise t.pos.error(f"expected 'command NAME(...) = {{ ... }}', found {self._show(t)}")
        self.next()
        nt = self.expect_name("the command's name")
        name = nt.text
        if name in KEYWORDS or name in TYPES:
            raise nt.pos.error(f"{name!r} is a reserved word")
        if name in ATOMS:
            raise nt.pos.error(f"{name!r} is an atomic command; choose another name")
        if name in self.defined_here:
            raise nt.pos.error(f"command {name!r} is defined twice (first at {self.lib[name].where})")
        self.expect_punct("(", "after the command's name")
        params: list[Param] = []
        if not self.is_punct(")"):
            while True:
                tt = self.expect_name("a parameter type (string, int, float or vector)")
                if tt.text not in TYPES:
                    raise tt.pos.error(f"unknown type {tt.text!r}: use string, int, float or vector")
                pt = self.expect_name("a parameter name")
                if pt.text in KEYWORDS or pt.text in TYPES:
                    raise pt.pos.error(f"{pt.text!r} is a reserved word")
                if any(p.name == pt.text for p in params):
                    raise pt.pos.error(f"parameter {pt.text!r} is declared twice")
                params.append(Param(pt.text, tt.text))
                if self.is_punct(","):
                    self.next()
                    continue
                break
        self.expect_punct(")", "to close the parameter list")
        self.expect_punct("=", "before the body ('command name(...) = { ... }')")
        is_async = False
        if self.tok.kind == "name" and self.tok.text == "async":
            is_async = True
            self.next()
        self.params = {p.name: p for p in params}
        body = self.block(0)
        if self.is_punct(";"):
            self.next()
        self.lib[name] = CompoundDef(name, tuple(params), body, nt.pos, is_async)
        self.defined_here.append(name)
        self.params = {}

    def block(self, depth: int) -> tuple[Any, ...]:
        if depth > MAX_DEPTH:
            raise self.tok.pos.error(f"async blocks nested more than {MAX_DEPTH} deep")
        self.expect_punct("{", "to open a block")
        stmts: list[Any] = []
        while not self.is_punct("}"):
            if self.tok.kind == "eof":
                raise self.tok.pos.error("missing '}' at the end of the file")
            stmts.append(self.statement(depth))
        self.next()
        return tuple(stmts)

    def statement(self, depth: int) -> Any:
        t = self.tok
        if t.kind == "name" and t.text == "async":
            self.next()
            body = self.block(depth + 1)
            if self.is_punct(";"):
                self.next()
            return AsyncBlock(body, t.pos)
        if t.kind == "name" and t.text == "sync":
            self.next()
            self.expect_punct(";", "after sync")
            return Sync(t.pos)
        if t.kind == "name" and t.text == "command":
            raise t.pos.error("a command cannot be defined inside another one (missing '}' before?)")
        call = self.call()
        self.expect_punct(";", "after the statement")
        return call

    def call(self) -> Call:
        nt = self.expect_name("a command call 'name(...);', 'async { ... }' or 'sync;'")
        self.expect_punct("(", f"after {nt.text!r} (a call is name(args);)")
        args: list[tuple[str | None, Expr]] = []
        seen_key = False
        if not self.is_punct(")"):
            while True:
                key = None
                if self.tok.kind == "name" and self.toks[self.i + 1].kind == "punct" and \
                        self.toks[self.i + 1].text == "=":
                    key = self.next().text
                    self.next()
                    seen_key = True
                elif seen_key:
                    raise self.tok.pos.error("positional argument after a name=value argument")
                args.append((key, self.expr()))
                if self.is_punct(","):
                    self.next()
                    continue
                break
        self.expect_punct(")", "to close the argument list")
        call = Call(nt.text, tuple(args), nt.pos)
        self.check_call(call)
        return call

    def expr(self, in_vector: bool = False) -> Expr:
        t = self.tok
        negate = False
        if self.is_punct("-"):
            negate = True
            self.next()
            t = self.tok
            if t.kind not in ("number", "name"):
                raise t.pos.error("'-' must be followed by a number or a numeric parameter")
        if t.kind == "number":
            self.next()
            return Literal(-t.value if negate else t.value, t.pos)
        if t.kind == "string":
            self.next()
            return Literal(t.value, t.pos)
        if t.kind == "name":
            self.next()
            p = self.params.get(t.text)
            if p is None:
                hint = " (strings need quotes)" if t.text not in ATOMS else ""
                raise t.pos.error(f"unknown name {t.text!r}: not a parameter of this command{hint}")
            if negate and p.type not in (INT, FLOAT):
                raise t.pos.error(f"'-' needs a numeric parameter, {t.text!r} is a {p.type}")
            return ParamRef(p.name, p.type, negate, t.pos)
        if self.is_punct("[") and not in_vector:
            self.next()
            items: list[Literal | ParamRef] = []
            if not self.is_punct("]"):
                while True:
                    e = self.expr(in_vector=True)
                    etype = type_name(e.value) if isinstance(e, Literal) else e.type  # type: ignore[union-attr]
                    if etype not in (INT, FLOAT):
                        raise e.pos.error(f"vector elements must be numbers, got a {etype}")
                    items.append(e)  # type: ignore[arg-type]
                    if self.is_punct(","):
                        self.next()
                        continue
                    break
            self.expect_punct("]", "to close the vector")
            if all(isinstance(x, Literal) for x in items):
                return Literal(tuple(float(x.value) for x in items), t.pos)  # type: ignore[union-attr, arg-type]
            return VectorExpr(tuple(items), t.pos)
        raise t.pos.error(f"expected a value (number, \"string\", [vector] or parameter), found {self._show(t)}")

    # checking
    def check_call(self, call: Call) -> None:
        target: Atom | CompoundDef | None = ATOMS.get(call.name) or self.lib.get(call.name)
        if target is None:
            raise call.pos.error(f"unknown command {call.name!r} (atomic commands: "
                                 f"{', '.join(n for n, a in ATOMS.items() if a.in_files)}; compound commands "
                                 "must be defined before they are used)")
        if isinstance(target, Atom) and not target.in_files:
            raise call.pos.error(f"{call.name} can be used on the console line only, not in a compound command")
        call.target = target
        if isinstance(target, Atom) and target.varargs:
            return
        static = [(k, static_value(e)) for k, e in call.args]
        try:
            bound = bind(call.name, target.params, static, self.n_joints, self.names)
        except ConsoleError as e:
            raise call.pos.error(e.message) from None
        if call.name == "run":
            f = bound["file"]
            if isinstance(f, Typed):
                raise call.pos.error("run needs a literal file name here (motion files are checked when this "
                                     "file is loaded)")
            if self.n_joints is not None:
                path = Path(f)
                if not path.is_absolute() and self.base_dir is not None and not path.exists():
                    path = self.base_dir / path
                try:
                    call.prepared = prepare_atom("run", {"file": str(path)}, self.n_joints, self.names or [])
                except ConsoleError as e:
                    raise call.pos.error(e.message) from None


def static_value(e: Expr) -> Value | Typed:
    if isinstance(e, Literal):
        return e.value
    if isinstance(e, ParamRef):
        return Typed(e.type)
    return Typed(VECTOR, len(e.items))


def parse_compound(text: str, file: str = "<commands>", *, n_joints: int | None = None,
                   names: list[str] | None = None, known: CompoundLibrary | None = None,
                   base_dir: Path | None = None) -> CompoundLibrary:
    """Parse and check a compound command file's text; returns the commands it defines.

    ``n_joints`` and ``names`` (the rig's) enable the vector-length, joint-name and motion-file
    checks; ``known`` are commands defined earlier that this text may call.
    """
    return _Parser(tokenize(text, file), file, n_joints, names, known or CompoundLibrary(), base_dir).file_()


def load_compound_file(path: str | Path, *, n_joints: int | None = None, names: list[str] | None = None,
                       known: CompoundLibrary | None = None) -> CompoundLibrary:
    """Read and parse a compound command file (UTF-8); motion files named by ``run`` are looked up
    relative to the working directory, then to the file's folder."""
    p = Path(path)
    try:
        data = read_limited(p, MAX_FILE_BYTES, "a compound command file")
    except ConfigError:
        raise CompoundError(str(p), 1, 1, f"file larger than {MAX_FILE_BYTES} bytes") from None
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        col = e.start - (data.rfind(b"\n", 0, e.start) + 1) + 1
        raise CompoundError(str(p), line, col, "the file is not UTF-8 text") from None
    return parse_compound(text, str(p), n_joints=n_joints, names=names, known=known, base_dir=p.parent)


def prepare(name: str, bound: dict[str, Any], n_joints: int, names: list[str], loop: Any = None) -> dict[str, Any]:
    """The off-loop phase of an atom sent on the console line; returns the arguments to run with.
    ``load`` reads and checks its compound file here (the atoms cannot import this language, which
    is built on them); the others as :func:`vmehil.console.commands.prepare` (``loop``: a motion
    is planned off the loop too)."""
    if name != "load":
        return prepare_atom(name, bound, n_joints, names, loop)
    check_console_file(bound["file"], "compound command file")
    try:
        lib = load_compound_file(bound["file"], n_joints=n_joints, names=names)
    except FileNotFoundError as e:
        raise ConsoleError(FILE, f"compound command file {bound['file']!r} not found ({e.strerror or e})") from None
    except (CompoundError, OSError, UnicodeDecodeError) as e:
        raise ConsoleError(FILE, str(e)) from None
    return {**bound, "library": lib}


# ---- execution --------------------------------------------------------------------------------------------
def evaluate(e: Expr, env: dict[str, Any]) -> Value:
    if isinstance(e, Literal):
        return e.value
    if isinstance(e, ParamRef):
        v = env[e.name]
        return -v if e.negate else v
    return tuple(float(evaluate(x, env)) for x in e.items)  # type: ignore[arg-type]


@dataclass
class _Frame:
    stmts: tuple[Any, ...]
    env: dict[str, Any]
    index: int = 0
    children: list[_Strand] = field(default_factory=list)


@dataclass
class _Strand:
    frames: list[_Frame]
    until: Callable[[Any], bool] | None = None
    until_pos: Pos | None = None
    pause: int = 0
    done: bool = False


@dataclass
class Invocation:
    id: int
    name: str
    strands: list[_Strand]
    started_tick: int


class Executor:
    """Runs compound command invocations, a bounded number of statements per tick.

    ``emit(line)`` receives the ``EVT`` lines (started/done/failed/cancelled and ``out`` lines of
    the statements' replies). All methods are called in the loop's thread at tick boundaries.
    """

    def __init__(self, session: Session, emit: Callable[[str], None], *, max_invocations: int = 16,
                 max_strands: int = 64, statements_per_tick: int = 32) -> None:
        self.session = session
        self.emit = emit
        self.max_invocations = max_invocations
        self.max_strands = max_strands
        self.statements_per_tick = statements_per_tick
        self.active: dict[int, Invocation] = {}
        self._next_id = 1
        self.statements_run = 0

    def active_ids(self) -> list[int]:
        return list(self.active)

    def start(self, defn: CompoundDef, env: dict[str, Any]) -> int:
        if len(self.active) >= self.max_invocations:
            raise ConsoleError(BUSY, f"{len(self.active)} compound commands are running already; wait or cancel")
        inv = Invocation(self._next_id, defn.name, [_Strand([_Frame(defn.body, dict(env))])],
                         int(self.session.loop.tick_count))
        self._next_id += 1
        self.active[inv.id] = inv
        self.session.loop.note(self.session.source, f"compound {defn.name} #{inv.id} started")
        return inv.id

    def cancel(self, inv_id: int, reason: str) -> int:
        inv = self.active.pop(inv_id, None)
        if inv is None:
            return 0
        self.emit(kv("EVT", "cancelled", str(inv.id), inv.name, reason=reason))
        return 1

    def cancel_all(self, reason: str) -> int:
        return sum(self.cancel(i, reason) for i in list(self.active))

    def step(self) -> None:
        """Advance every invocation (call once per tick, at the tick boundary)."""
        budget = self.statements_per_tick
        for inv in list(self.active.values()):
            if inv.id not in self.active:
                continue
            try:
                budget = self._step_invocation(inv, budget)
            except ConsoleError as e:
                self._fail(inv, e.code, e.message)
            except _StatementError as e:
                self._fail(inv, e.code, f"{e.pos}: {e.message}")
            if inv.id in self.active and all(s.done for s in inv.strands):
                del self.active[inv.id]
                self.emit(kv("EVT", "done", str(inv.id), inv.name,
                             ticks=int(self.session.loop.tick_count) - inv.started_tick))
                self.session.loop.note(self.session.source, f"compound {inv.name} #{inv.id} done")

    def _fail(self, inv: Invocation, code: str, message: str) -> None:
        if self.active.pop(inv.id, None) is not None:
            self.emit(kv("EVT", "failed", str(inv.id), inv.name, code, one_line(message)))
            self.session.loop.note(self.session.source, f"compound {inv.name} #{inv.id} failed: {message}")

    def _step_invocation(self, inv: Invocation, budget: int) -> int:
        i = 0
        while i < len(inv.strands):
            st = inv.strands[i]
            i += 1
            if st.done:
                continue
            budget = self._run_strand(inv, st, budget)
            if inv.id not in self.active:  # a statement stopped or cancelled it
                return budget
        return budget

    def _run_strand(self, inv: Invocation, st: _Strand, budget: int) -> int:
        loop = self.session.loop
        while inv.id in self.active:
            if st.until is not None:
                if st.until(loop):
                    st.until = None
                elif loop.fault is not None:
                    raise _StatementError(STATE, st.until_pos, f"the loop stopped ({loop.fault.cause}) "
                                                               "while this statement's motion was running")
                else:
                    return budget
            if st.pause > 0:
                st.pause -= 1
                return budget
            if not st.frames:
                st.done = True
                return budget
            fr = st.frames[-1]
            if fr.index >= len(fr.stmts):
                if any(not c.done for c in fr.children):
                    return budget
                st.frames.pop()
                continue
            stmt = fr.stmts[fr.index]
            if isinstance(stmt, Sync):
                if any(not c.done for c in fr.children):
                    return budget
                fr.index += 1
                continue
            if budget <= 0:
                return budget
            budget -= 1
            fr.index += 1
            self.statements_run += 1
            if isinstance(stmt, AsyncBlock):
                if len(inv.strands) >= self.max_strands:
                    raise _StatementError(BUSY, stmt.pos, f"more than {self.max_strands} concurrent blocks")
                child = _Strand([_Frame(stmt.body, fr.env)])
                fr.children.append(child)
                inv.strands.append(child)
                continue
            self._call(inv, st, stmt)
        return budget

    def _call(self, inv: Invocation, st: _Strand, call: Call) -> None:
        s = self.session
        target = call.target
        values = [(k, evaluate(e, st.frames[-1].env)) for k, e in call.args]
        try:
            if isinstance(target, CompoundDef):
                if len(st.frames) >= MAX_DEPTH:
                    raise ConsoleError(BUSY, f"compound commands nested more than {MAX_DEPTH} deep")
                env = bind(target.name, target.params, values, s.n, s.names)
                st.frames.append(_Frame(target.body, env))
                return
            if target.varargs:
                bound: dict[str, Any] = {"args": []}
            else:
                bound = bind(target.name, target.params, values, s.n, s.names)
            if call.prepared is not None:
                bound = {**bound, **{k: v for k, v in call.prepared.items() if k not in bound}}
            outcome = target.run(s, bound)
        except ConsoleError as e:
            raise _StatementError(e.code, call.pos, e.message) from None
        except Exception as e:  # a bug must not take the loop down
            raise _StatementError(INTERNAL, call.pos, f"{type(e).__name__}: {e}") from None
        for line in outcome.lines:
            self.emit(f"EVT out {inv.id} {line}")
        if outcome.until is not None:
            st.until = outcome.until
            st.until_pos = call.pos
        if outcome.pause_ticks > 0:
            st.pause = outcome.pause_ticks

    def __iter__(self) -> Iterator[Invocation]:
        return iter(self.active.values())


class _StatementError(VmehilError):
    def __init__(self, code: str, pos: Pos | None, message: str) -> None:
        self.code, self.pos, self.message = code, pos, message
        super().__init__(message)
