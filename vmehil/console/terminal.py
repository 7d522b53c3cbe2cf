"""The operator's side of a console line: a prompt, echo of what is typed, and history.

A raw pty or serial line has no line discipline: without this a person in ``picocom`` or
``socat -,raw,echo=0`` sees no prompt and nothing of what they type. :class:`TerminalView`
sits between the console and the transport:

* **echo** (``echo=True``): every byte typed is shown back as the line it edits — printable
  characters, backspace (``BS SP BS``), Ctrl-C/Ctrl-U (the line redrawn empty), Enter (CR LF);
* **prompt** (``prompt="> "``): always the last thing on the screen. Output (replies, events)
  first erases the prompt line (CR, ANSI ``ESC [ K``), then writes its lines, then draws the
  prompt again with the line being typed, so an event arriving mid-typing does not mangle it;
* **history** (with echo): up/down recall the last :data:`HISTORY` lines (ANSI cursor keys, taken
  out of the input by :class:`~vmehil.console.protocol.LineAssembler`); other keys are swallowed.

Both off, bytes pass as before (a script's line protocol). The view never blocks the loop: it
runs in the console's reader and writer threads, serialised by one lock.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

from vmehil.console.protocol import LineAssembler, LineEvent

HISTORY = 100  #: lines kept for up/down recall
ERASE_LINE = b"\r\x1b[K"  #: carriage return, then erase to the end of the line (ANSI EL)


class TerminalView:
    """Prompt, echo and history on one console line (see the module docstring)."""

    def __init__(self, write: Callable[[bytes], None], *, prompt: str | None = "> ", echo: bool = True,
                 history: int = HISTORY) -> None:
        self._write = write
        self.prompt = (prompt or "").encode("ascii", errors="replace")
        self.echo = echo
        self._lock = threading.Lock()
        self._shown = ""  # the typed line as it is on the screen (echo)
        self._visible = False  # prompt and/or typed line are on the screen's last line
        self._history: list[str] = []
        self._max_history = history
        self._recall: int | None = None  # index into the history while recalling
        self._last = 0

    @property
    def active(self) -> bool:
        return bool(self.prompt) or self.echo

    def reset(self) -> None:
        """A new terminal: nothing typed, nothing on its screen yet (history kept)."""
        with self._lock:
            self._shown, self._visible, self._recall, self._last = "", False, None, 0

    # ---- input side (the reader thread) ---------------------------------------------------------------
    def feed(self, data: bytes, assembler: LineAssembler) -> list[LineEvent]:
        """Feed ``data`` to ``assembler`` byte by byte, echoing; returns its line events (keys used)."""
        events: list[LineEvent] = []
        for b in data:
            got = assembler.feed(bytes((b,)))
            keys = [e for e in got if e.kind == "key"]
            lines = [e for e in got if e.kind != "key"]
            events.extend(lines)
            with self._lock:
                if b in (0x0A, 0x0D):
                    if not (b == 0x0A and self._last == 0x0D):  # CR LF is one Enter
                        self._enter([e.text for e in lines if e.kind == "line"])
                elif keys:
                    for k in keys:
                        self._key(k.text, assembler)
                else:
                    self._sync(assembler.pending)
                self._last = b
        return events

    def _enter(self, texts: list[str]) -> None:
        for t in texts:
            if t.strip() and (not self._history or self._history[-1] != t):
                self._history.append(t)
                del self._history[:-self._max_history]
        self._recall = None
        self._shown = ""
        if self.echo:
            self._write(b"\r\n")
        self._write(self.prompt)
        self._visible = True

    def _key(self, name: str, assembler: LineAssembler) -> None:
        if not self.echo or name not in ("up", "down") or not self._history:
            return  # other keys (and recall without echo: invisible) are swallowed
        if name == "up":
            self._recall = len(self._history) - 1 if self._recall is None else max(0, self._recall - 1)
            text = self._history[self._recall]
        elif self._recall is None:
            return
        elif self._recall + 1 < len(self._history):
            self._recall += 1
            text = self._history[self._recall]
        else:
            self._recall, text = None, ""
        assembler.replace(text)
        self._redraw(text)

    def _sync(self, pending: str) -> None:
        """Show what the last byte did to the typed line."""
        if not self.echo or pending == self._shown:
            return
        if pending.startswith(self._shown):
            self._write(_ascii(pending[len(self._shown):]))
        elif self._shown.startswith(pending) and len(self._shown) - len(pending) == 1:  # backspace
            n = len(_ascii(self._shown)) - len(_ascii(pending))  # as many cells as the echo took
            self._write(b"\b \b" * n)
        else:
            self._redraw(pending)
            return
        self._shown = pending
        self._visible = True

    def _redraw(self, text: str) -> None:
        self._write(ERASE_LINE + self.prompt + _ascii(text))
        self._shown = text
        self._visible = True

    # ---- output side (the writer thread) --------------------------------------------------------------
    def output(self, data: bytes) -> None:
        """Write reply/event lines: erase the prompt line, write, draw the prompt and typed line again."""
        with self._lock:
            if self._visible:
                self._write(ERASE_LINE)
            self._write(data)
            typed = _ascii(self._shown) if self.echo else b""
            self._write(self.prompt + typed)
            self._visible = bool(self.prompt or typed)


def _ascii(text: str) -> bytes:
    from vmehil.writers.ascii_text import to_ascii

    return to_ascii(text).encode("ascii", errors="replace")
