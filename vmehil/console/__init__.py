"""Operator console on a serial line (pty, device or pyserial URL). See docs/console.md.

Modules: :mod:`~vmehil.console.protocol` (line protocol and replies), :mod:`~vmehil.console.commands`
(atomic commands), :mod:`~vmehil.console.compound` (compound-command files), :mod:`~vmehil.console.server`
(transports, threads, hand-over at tick boundaries), :mod:`~vmehil.console.extension`
(``vmehil run --console``).
"""

from vmehil.console.compound import CompoundError, CompoundLibrary, load_compound_file, parse_compound
from vmehil.console.protocol import ConsoleError, parse_line, parse_reply_line
from vmehil.console.server import Console, ConsoleSetupError, open_transport

__all__ = [
    "CompoundError",
    "CompoundLibrary",
    "Console",
    "ConsoleError",
    "ConsoleSetupError",
    "load_compound_file",
    "open_transport",
    "parse_compound",
    "parse_line",
    "parse_reply_line",
]
