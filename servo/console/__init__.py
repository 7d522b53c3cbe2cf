"""Operator console on a serial line (pty, device or pyserial URL). See docs/console.md.

Modules: :mod:`~servo.console.protocol` (line protocol and replies), :mod:`~servo.console.commands`
(atomic commands), :mod:`~servo.console.compound` (compound-command files), :mod:`~servo.console.server`
(transports, threads, hand-over at tick boundaries), :mod:`~servo.console.extension`
(``vmehil run --console``).
"""

from servo.console.compound import CompoundError, CompoundLibrary, load_compound_file, parse_compound
from servo.console.protocol import ConsoleError, parse_line, parse_reply_line
from servo.console.server import Console, ConsoleSetupError, open_transport

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
