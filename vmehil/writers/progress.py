"""Every progress display of the command line: a tqdm bar on stderr.

A bar is shown only when stderr is a terminal and ``--quiet`` was not given; otherwise nothing
is drawn (pipes and log files get no carriage returns). While a bar is shown, lines must not be
printed onto it: :func:`say` prints a line through ``tqdm.write`` (the bar is cleared, the line
printed, the bar drawn again below it), and while a bar is open the root logger's console
handlers, logging's last-resort handler and :mod:`warnings` are routed the same way.

Three shapes of progress, one per caller:

* :func:`progress_bar`: a context manager yielding the bar (``tune sweep``: one step per point);
* :class:`TickProgress`: ``progress(i, n)`` for :meth:`servo.runner.LockstepRunner.run` (``run``,
  and the ``tune`` simulations);
* :class:`PhaseProgress`: ``progress(what, i, n)`` of the calibration procedures, with
  :meth:`~PhaseProgress.say` and :meth:`~PhaseProgress.ask` for their lines and prompts.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import warnings
from collections.abc import Callable, Iterator
from typing import Any, TextIO

from tqdm import tqdm


class _Bar(tqdm):
    # tqdm's monitor thread only corrects refresh rates of slow loops; the real-time servo
    # loop shares this process and gets no extra thread waking up beside it.
    monitor_interval = 0


def shows(stream: TextIO | None = None, *, quiet: bool = False) -> bool:
    """True when a bar would be drawn on ``stream`` (default stderr): a terminal, not quiet."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return not quiet and callable(isatty) and bool(isatty())


def say(text: Any) -> None:
    """``print(text)`` that never lands on a progress bar's line."""
    tqdm.write(str(text))


class _WriteAboveBar(logging.Handler):
    """Log records to stderr through ``tqdm.write`` (stands in for logging's last resort)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:
            self.handleError(record)


@contextlib.contextmanager
def _lines_above_bar() -> Iterator[None]:
    """Route log records and warnings through ``tqdm.write`` while a bar is open."""
    from tqdm.contrib.logging import logging_redirect_tqdm  # imports tqdm.auto: only when a bar shows

    last_resort, show_warning = logging.lastResort, warnings.showwarning

    def warning_above_bar(message, category, filename, lineno, file=None, line=None) -> None:
        tqdm.write(warnings.formatwarning(message, category, filename, lineno, line).rstrip("\n"),
                   file=sys.stderr if file is None else file)

    resort = _WriteAboveBar(logging.WARNING)
    try:
        logging.lastResort = resort
        warnings.showwarning = warning_above_bar
        with logging_redirect_tqdm(tqdm_class=_Bar):
            yield
    finally:
        logging.lastResort, warnings.showwarning = last_resort, show_warning


@contextlib.contextmanager
def progress_bar(desc: str, total: int | None, *, quiet: bool = False, leave: bool = True, unit: str = "it",
                 stream: TextIO | None = None, initial: int = 0) -> Iterator[tqdm]:
    """A bar on ``stream`` (default stderr), disabled (every call a no-op) unless :func:`shows`;
    closed on exit, left on screen with ``leave``; ``initial``: already done (a resumed sweep)."""
    stream = sys.stderr if stream is None else stream
    bar = _Bar(total=total, desc=desc, unit=unit, leave=leave, file=stream, dynamic_ncols=True,
               disable=not shows(stream, quiet=quiet), initial=initial)
    try:
        if bar.disable:
            yield bar
        else:
            with _lines_above_bar():
                yield bar
    finally:
        bar.close()


class _BarOnDemand:
    """A bar opened by the first progress call (when the caller's ``n`` is known) and closed by
    the last, by :meth:`close` or at the end of a ``with`` block."""

    def __init__(self, *, quiet: bool, stream: TextIO | None) -> None:
        self.stream = stream
        self.enabled = shows(stream, quiet=quiet)
        self._open = contextlib.ExitStack()
        self._bar: tqdm | None = None

    def _new_bar(self, desc: str, n: int, **kw: Any) -> tqdm:
        self.close()
        self._bar = self._open.enter_context(progress_bar(desc, n, stream=self.stream, **kw))
        return self._bar

    def close(self) -> None:
        self._bar = None
        self._open.close()

    def __enter__(self) -> Any:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class TickProgress(_BarOnDemand):
    """``progress(i, n)`` for a runner's ``run(n_ticks, progress=...)``: a bar over the ticks.

    Pass ``progress if progress.enabled else None`` to a real-time run, so that a run without a
    display costs nothing per tick."""

    def __init__(self, desc: str, *, quiet: bool = False, stream: TextIO | None = None) -> None:
        super().__init__(quiet=quiet, stream=stream)
        self.desc = desc

    def __call__(self, i: int, n: int) -> None:
        if not self.enabled:
            return
        bar = self._bar or self._new_bar(self.desc, n, unit="tick")
        bar.update(i - bar.n)
        if i >= n:
            self.close()


class PhaseProgress(_BarOnDemand):
    """``progress(what, i, n)`` of the calibration procedures (``ctx.progress``): one bar per
    phase, cleared when it completes; a new phase starts when ``n`` changes or ``i`` goes back
    (a new ``what`` at the same count only relabels the bar: ``adc adc0``, ``adc adc1``…).

    :meth:`say` and :meth:`ask` are ``ctx.say`` and ``ctx.prompt``: they print above the bar."""

    def __init__(self, *, quiet: bool = False, stream: TextIO | None = None,
                 answer: Callable[[str], str] = input) -> None:
        super().__init__(quiet=quiet, stream=stream)
        self.answer = answer

    def __call__(self, what: str, i: int, n: int) -> None:
        if not self.enabled or n <= 0:
            return
        bar = self._bar
        if bar is None or bar.total != n or i < bar.n:
            bar = self._new_bar(what, n, leave=False)
        elif bar.desc != what:
            bar.set_description_str(what, refresh=False)
        bar.update(i - bar.n)
        if i >= n:
            self.close()

    def say(self, text: Any) -> None:
        say(text)

    def ask(self, question: str) -> str:
        """The operator's answer to ``question``, asked on a line of its own (bar cleared meanwhile)."""
        with tqdm.external_write_mode():
            return self.answer(question)
