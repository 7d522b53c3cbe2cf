"""The error a subcommand raises for the user: printed without a traceback, exit status 2.

It lives in :mod:`vmehil.errors` beside the package's root (modules below the commands refuse
bad input with it too); this name stays for the commands and for scripts that import it here."""

from vmehil.errors import CliError

__all__ = ["CliError"]
