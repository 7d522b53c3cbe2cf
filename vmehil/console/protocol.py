"""The console's line protocol: request lines in, status-prefixed reply lines out.

Requests (one per line, ``\\r``, ``\\n`` or ``\\r\\n`` terminated, at most :data:`MAX_LINE` bytes)::

    NAME [ARG ...]          ARG = VALUE | KEY=VALUE
    VALUE = 12 | -1.5e-3 | word | "quoted string" | [1, 2, 3] | 1,2,3

Numbers become ``int`` or ``float``, a bracketed or comma-joined list becomes a vector (a tuple
of floats), anything else a string. ``#`` starts a comment line. Backspace/DEL edit the line being
typed, Ctrl-C / Ctrl-U discard it; ANSI escape sequences (arrow keys) are taken out.

Replies: every line starts with a prefix, and each reply ends with exactly one ``OK`` or ``ERR``
line (the end marker)::

    DATA <key=value ...>             data lines of a reply (zero or more)
    INFO <text>                      human remarks of a reply (zero or more)
    OK <command> [key=value ...]     success, end of the reply
    ERR <CODE> <message>             failure, end of the reply
    EVT <kind> [...]                 asynchronous events, never inside a reply

Values in key=value pairs containing spaces, quotes or ``=`` are JSON-quoted, so a reply line
splits with :func:`shlex.split` (or :func:`parse_reply_line`).
"""

from __future__ import annotations

import json
import math
import re
import shlex
from dataclasses import dataclass
from typing import Union

from vmehil.errors import VmehilError

MAX_LINE = 512  # bytes per request line (without the terminator)
REPLY_PREFIXES = ("OK", "ERR", "DATA", "INFO", "EVT")

# error codes (the word after ERR)
SYNTAX = "SYNTAX"  # the line could not be parsed
UNKNOWN = "UNKNOWN"  # no such command
ARGS = "ARGS"  # wrong arguments (count, names, types)
VALUE = "VALUE"  # an argument has the right type but a bad value
GAIN = "GAIN"  # gain change rejected by servo.gain_guard
STATE = "STATE"  # not possible now (motion running, loop faulted, ...)
BUSY = "BUSY"  # the console's queue is full: the line was dropped
LONG = "LONG"  # the line was longer than MAX_LINE bytes and was discarded
BINARY = "BINARY"  # the line held bytes that are not text
FILE = "FILE"  # a file could not be read or parsed
UNAVAILABLE = "UNAVAILABLE"  # the feature is not in this build / not offered by this host
INTERNAL = "INTERNAL"  # a bug: the command raised an unexpected exception
LIMIT = "LIMIT"  # a move's target past a joint's soft limit (docs/motion-safety.md)
COLLISION = "COLLISION"  # a move's path through an obstacle of the scene
REACH = "REACH"  # a point the arm cannot reach
NOT_HOMED = "NOT_HOMED"  # the rig requires homing before moves, and a joint is not homed
GRASP = "GRASP"  # the hand's tactile switches and hand pot disagree about a grasp (docs/hand.md)
ERROR_CODES = (SYNTAX, UNKNOWN, ARGS, VALUE, GAIN, STATE, BUSY, LONG, BINARY, FILE, UNAVAILABLE, INTERNAL, LIMIT,
               COLLISION, REACH, NOT_HOMED, GRASP)

Vector = tuple[float, ...]
Value = Union[str, int, float, Vector]  # noqa: UP007 - a runtime alias

NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
INT_RE = re.compile(r"[+-]?[0-9]+\Z")
FLOAT_RE = re.compile(r"[+-]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][+-]?[0-9]+)?\Z")
KEY_RE = re.compile(r"([A-Za-z_][A-Za-z0-9_]*)=")


class ConsoleError(VmehilError):
    """A typed console error: ``code`` (one of :data:`ERROR_CODES`) and a message saying what to do."""

    def __init__(self, code: str, message: str) -> None:
        if code not in ERROR_CODES:
            raise ValueError(f"unknown console error code {code!r}")
        self.code = code
        self.message = message
        super().__init__(f"{code} {message}")

    def reply_line(self) -> str:
        return f"ERR {self.code} {one_line(self.message)}"


def type_name(value: Value) -> str:
    """``string``, ``int``, ``float`` or ``vector`` — the compound language's parameter types."""
    if isinstance(value, tuple):
        return "vector"
    if isinstance(value, bool):
        return "string"
    if isinstance(value, int):
        return "int"
    if isinstance(value, float):
        return "float"
    return "string"


@dataclass(frozen=True)
class Arg:
    """One argument of a request: ``key`` (None when positional), ``value``, ``col`` (1-based)."""

    key: str | None
    value: Value
    col: int = 0


@dataclass(frozen=True)
class Request:
    """A parsed request line."""

    name: str
    args: tuple[Arg, ...]
    text: str


def number(text: str) -> int | float | None:
    """``text`` as an int or a finite float, else None."""
    if INT_RE.match(text):
        return int(text)
    if FLOAT_RE.match(text):
        v = float(text)
        return v if math.isfinite(v) else None
    return None


def _vector(text: str, col: int) -> Vector:
    parts = [p for p in re.split(r"[,\s]+", text.strip()) if p]
    out = []
    for p in parts:
        v = number(p)
        if v is None:
            raise ConsoleError(SYNTAX, f"column {col}: vector element {p!r} is not a number")
        out.append(float(v))
    return tuple(out)


def _split(line: str) -> list[tuple[str, int]]:
    """Split on whitespace outside quotes and brackets → (raw token, 1-based column)."""
    tokens: list[tuple[str, int]] = []
    i, n = 0, len(line)
    while i < n:
        if line[i].isspace():
            i += 1
            continue
        start = i
        while i < n and not line[i].isspace():
            c = line[i]
            if c == '"':
                i += 1
                while i < n and line[i] != '"':
                    i += 2 if line[i] == "\\" else 1
                if i >= n:
                    raise ConsoleError(SYNTAX, f"column {start + 1}: unterminated string (missing \")")
            elif c == "[":
                j = line.find("]", i)
                if j < 0:
                    raise ConsoleError(SYNTAX, f"column {i + 1}: unterminated vector (missing ])")
                i = j
            i += 1
        tokens.append((line[start:i], start + 1))
    return tokens


def _unquote(raw: str, col: int) -> str:
    try:
        value = json.loads(raw, strict=False)
    except ValueError:
        value = None
    if not isinstance(value, str):
        raise ConsoleError(SYNTAX, f"column {col}: a string is \"text\" (escapes \\\" and \\\\), "
                                   "with nothing after the closing quote")
    return value


def _value(raw: str, col: int) -> Value:
    if raw.startswith('"'):
        return _unquote(raw, col)
    if '"' in raw:
        raise ConsoleError(SYNTAX, f"column {col}: a quote inside a word; quote the whole value")
    if raw.startswith("["):
        if not raw.endswith("]") or raw.count("[") != 1 or raw.count("]") != 1:
            raise ConsoleError(SYNTAX, f"column {col}: a vector is [a, b, ...] with numbers inside")
        return _vector(raw[1:-1], col)
    if "[" in raw or "]" in raw:
        raise ConsoleError(SYNTAX, f"column {col}: a vector is [a, b, ...] with numbers inside")
    v = number(raw)
    if v is not None:
        return v
    if "," in raw:
        return _vector(raw, col)
    return raw


def parse_line(line: str) -> Request | None:
    """Parse one request line; None for a blank or comment line; :class:`ConsoleError` (SYNTAX) else."""
    text = line.strip()
    if not text or text.startswith("#"):
        return None
    tokens = _split(line)
    name, col = tokens[0]
    if not NAME_RE.match(name):
        raise ConsoleError(SYNTAX, f"column {col}: a command name (letters, digits, _) is expected, "
                                   f"got {name[:40]!r}; try help")
    args: list[Arg] = []
    seen_key = False
    for raw, col in tokens[1:]:
        m = KEY_RE.match(raw)
        if m is not None:
            rest = raw[m.end():]
            if not rest:
                raise ConsoleError(SYNTAX, f"column {col}: {m.group(1)}= needs a value")
            args.append(Arg(m.group(1), _value(rest, col + m.end()), col))
            seen_key = True
            continue
        if seen_key:
            raise ConsoleError(SYNTAX, f"column {col}: positional argument after a key=value argument")
        args.append(Arg(None, _value(raw, col), col))
    return Request(name, tuple(args), text)


# ---- replies -----------------------------------------------------------------------------------------
def one_line(text: str) -> str:
    """Make ``text`` safe for one reply line (no line breaks or control characters)."""
    return "".join(c if c.isprintable() else " " for c in str(text).replace("\r", " ").replace("\n", " "))


def fmt_value(v: object) -> str:
    """A value for a ``key=value`` pair: numbers compactly (``nan`` for missing), strings quoted if needed."""
    if isinstance(v, bool):
        return "1" if v else "0"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        return f"{v:.6g}"
    if isinstance(v, tuple | list):
        return "[" + ",".join(fmt_value(x) for x in v) + "]"
    s = one_line(str(v))
    if s == "" or any(c.isspace() or c in "\"'=\\" for c in s):
        return json.dumps(s, ensure_ascii=False)
    return s


def kv(*head: str, **pairs: object) -> str:
    """``head words`` followed by ``key=value`` pairs, formatted by :func:`fmt_value`."""
    parts = [one_line(h) for h in head]
    parts += [f"{k}={fmt_value(v)}" for k, v in pairs.items()]
    return " ".join(parts)


def parse_reply_line(line: str) -> tuple[str, list[str], dict[str, str]]:
    """Split a reply line into (prefix, words, key→value) — for scripts and tests."""
    parts = shlex.split(line, posix=True)
    if not parts or parts[0] not in REPLY_PREFIXES:
        raise ValueError(f"not a console reply line: {line!r}")
    words, pairs = [], {}
    for p in parts[1:]:
        k, sep, v = p.partition("=")
        if sep and NAME_RE.match(k):
            pairs[k] = v
        else:
            words.append(p)
    return parts[0], words, pairs


# ---- bytes → lines --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LineEvent:
    """What the assembler produced: ``kind`` ``"line"`` (``text``), ``"long"``, ``"binary"`` or
    ``"key"`` (``text``: the cursor key's name; only with ``LineAssembler(keys=True)``)."""

    kind: str
    text: str = ""


#: the keys an ANSI terminal sends as escape sequences: CSI (ESC [ … final) or SS3 (ESC O x)
_KEYS = {"A": "up", "B": "down", "C": "right", "D": "left", "H": "home", "F": "end"}
_CSI_TILDE_KEYS = {"1": "home", "2": "insert", "3": "delete", "4": "end", "5": "page_up", "6": "page_down",
                   "7": "home", "8": "end"}
_MAX_ESCAPE = 32  # bytes of one escape sequence's parameters before it is given up


class LineAssembler:
    """Turns a byte stream into request lines, robust against garbage.

    * ``\\r`` and ``\\n`` end a line (``\\r\\n`` gives one line and one ignored blank line);
    * backspace (0x08) and DEL (0x7f) delete the previous byte, Ctrl-C (0x03) and Ctrl-U (0x15)
      discard the line typed so far;
    * ANSI escape sequences (arrow and function keys: ``ESC [ … final``, ``ESC O x``, ``ESC x``)
      are taken out of the line; with ``keys=True`` the cursor keys come out as ``key`` events
      (``text`` ``up``, ``down``, ``left``, ``right``, ``home``, ``end``, ``delete``, …);
    * a line longer than ``max_line`` bytes is discarded up to its terminator and reported once
      as ``long``; a line holding other control bytes or invalid UTF-8 is reported as ``binary``.

    Memory is bounded by ``max_line`` whatever arrives.
    """

    def __init__(self, max_line: int = MAX_LINE, *, keys: bool = False) -> None:
        self.max_line = max_line
        self.keys = keys
        self._buf = bytearray()
        self._overflow = False
        self._binary = False
        self._esc = ""  # "" outside a sequence; "\x1b" after ESC; "[" or "O" inside CSI / SS3
        self._esc_params = ""

    @property
    def pending(self) -> str:
        """The line typed so far (what an echoing terminal shows)."""
        return "" if self._overflow else self._buf.decode("utf-8", errors="replace")

    def replace(self, text: str) -> None:
        """Replace the line typed so far (history recall)."""
        data = text.encode("utf-8")[: self.max_line]
        self._buf[:] = data
        self._overflow = False
        self._binary = any(b < 0x20 and b != 0x09 for b in data)

    def _escape(self, b: int, out: list[LineEvent]) -> bool:
        """Consume ``b`` as part of an escape sequence; False when ``b`` is not one (process it)."""
        c = chr(b)
        if self._esc == "\x1b":
            self._esc = c if c in "[O" else ""  # ESC x (Alt-x): both bytes swallowed
            self._esc_params = ""
            return True
        if self._esc == "O":
            self._esc = ""
            self._key(_KEYS.get(c), out)
            return True
        # CSI: parameter and intermediate bytes 0x20-0x3F, then a final byte 0x40-0x7E
        if 0x20 <= b <= 0x3F and len(self._esc_params) < _MAX_ESCAPE:
            self._esc_params += c
            return True
        self._esc = ""
        if 0x40 <= b <= 0x7E:
            name = _CSI_TILDE_KEYS.get(self._esc_params.split(";")[0]) if c == "~" else _KEYS.get(c)
            self._key(name, out)
            return True
        return False  # a broken sequence: this byte is input again

    def _key(self, name: str | None, out: list[LineEvent]) -> None:
        if self.keys and name is not None:
            out.append(LineEvent("key", name))

    def feed(self, data: bytes) -> list[LineEvent]:
        out: list[LineEvent] = []
        for b in data:
            if self._esc and self._escape(b, out):
                continue
            if b == 0x1B:
                self._esc = "\x1b"
            elif b in (0x0A, 0x0D):
                out.extend(self._finish())
            elif b in (0x08, 0x7F):
                if self._buf and not self._overflow:
                    self._buf.pop()
                    while self._buf and 0x80 <= self._buf[-1] < 0xC0:  # a whole UTF-8 character
                        self._buf.pop()
                    if self._buf and self._buf[-1] >= 0xC0:
                        self._buf.pop()
            elif b in (0x03, 0x15):
                self._buf.clear()
                self._overflow = self._binary = False
            elif self._overflow:
                continue
            else:
                if b < 0x20 and b != 0x09:
                    self._binary = True
                if len(self._buf) >= self.max_line:
                    self._overflow = True
                    self._buf.clear()
                    continue
                self._buf.append(b)
        return out

    def _finish(self) -> list[LineEvent]:
        buf, overflow, binary = bytes(self._buf), self._overflow, self._binary
        self._buf.clear()
        self._overflow = self._binary = False
        if overflow:
            return [LineEvent("long")]
        if not buf:
            return []
        if binary:
            return [LineEvent("binary")]
        try:
            text = buf.decode("utf-8")
        except UnicodeDecodeError:
            return [LineEvent("binary")]
        if not all(c.isprintable() or c == "\t" for c in text):
            return [LineEvent("binary")]
        return [LineEvent("line", text)]


def is_reply_line(text: str) -> bool:
    """True for a line that looks like one of our replies (ignored as input: a loopback or an
    echoing terminal must not feed replies back as commands)."""
    word = text.strip().split(" ", 1)[0]
    return word in REPLY_PREFIXES
