"""``vmehil`` subcommands, one module each.

What only some commands need is an extra of the package (pyproject.toml). Such a command, or
option, imports it only when it runs, and checks first (:func:`needs_extra`,
:func:`missing_extra`): without the extra it says in one line what to install, exit status 2.
"""

from __future__ import annotations

import functools
import importlib
import sys
from collections.abc import Callable
from typing import TypeVar

_Options = TypeVar("_Options")

#: The modules each extra of pyproject.toml brings, as the commands import them.
EXTRA_MODULES: dict[str, tuple[str, ...]] = {
    "tune": ("control", "scipy", "matplotlib"),
    "plots": ("matplotlib",),
    "mavlink": ("pymavlink",),
    "console": ("serial",),
    "dask": ("dask", "distributed"),
    "trace": ("mcap", "vcd", "pyarrow", "foxglove"),
}


def missing_extra(what: str, extra: str) -> str | None:
    """None when every module of ``extra`` imports; else the line saying that ``what`` needs it."""
    for name in EXTRA_MODULES[extra]:
        try:
            importlib.import_module(name)
        except ImportError:
            return f"{what} needs the '{extra}' extra: pip install 'vmehil[{extra}]'"
    return None


def refuse_without(what: str, extra: str) -> bool:
    """Print :func:`missing_extra`'s line to stderr and return True when ``extra`` is missing."""
    line = missing_extra(what, extra)
    if line is not None:
        print(line, file=sys.stderr)
    return line is not None


def needs_extra(extra: str, what: str) -> Callable[[Callable[[_Options], int]], Callable[[_Options], int]]:
    """Decorate a command function (``what``: the command, as its refusal names it, e.g.
    ``vmehil tune``): without ``extra`` it returns 2 after one line on stderr."""

    def wrap(func: Callable[[_Options], int]) -> Callable[[_Options], int]:
        @functools.wraps(func)
        def command(options: _Options) -> int:
            if refuse_without(what, extra):
                return 2
            return func(options)

        return command

    return wrap


def console_port_needs_serial(port: str) -> bool:
    """Whether the console PORT is served through pyserial (the 'console' extra): every port but a
    pty and a listen:// socket (see :func:`vmehil.console.server.open_transport`)."""
    return not (port == "pty" or port.startswith(("pty:", "listen://")))
