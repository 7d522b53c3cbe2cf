"""The root of every typed error of the application (vmehil).

Each error the package raises derives from :class:`VmehilError`, so a caller can catch the package's
errors in one clause (the ``vmehil`` command line catches the four roots). An error that is also a
builtin kind keeps it by multiple inheritance (``class FooError(VmehilError, ValueError)``), so
``except ValueError`` still works where callers rely on it. tests/test_exception_roots.py checks
that no exception class of the package stands outside this root.
"""

__all__ = ["CliError", "VmehilError"]


class VmehilError(Exception):
    """Any typed error of the application (vmehil)."""


class CliError(VmehilError, ValueError):
    """Bad input: a flag, a file or a key the application refuses — printed without a traceback,
    exit status 2 (nothing moved). A ``ValueError`` too, so callers that catch the refused value
    as one keep working."""
