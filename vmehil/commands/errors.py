"""The error a subcommand raises for the user: printed without a traceback, exit status 2."""


class CliError(Exception):
    """A user-facing error: printed without a traceback, exit status 2."""
