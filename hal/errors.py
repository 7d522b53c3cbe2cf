"""The root of every typed error of drivers, register maps, the bus and their configuration (hal).

Each error the package raises derives from :class:`HalError`, so a caller can catch the package's
errors in one clause (the ``vmehil`` command line catches the four roots). An error that is also a
builtin kind keeps it by multiple inheritance (``class FooError(HalError, ValueError)``), so
``except ValueError`` still works where callers rely on it. tests/test_exception_roots.py checks
that no exception class of the package stands outside this root.
"""

__all__ = ["HalError"]


class HalError(Exception):
    """Any typed error of drivers, register maps, the bus and their configuration (hal)."""
