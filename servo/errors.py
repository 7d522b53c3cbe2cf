"""The root of every typed error of the controller (servo).

Each error the package raises derives from :class:`ServoError`, so a caller can catch the package's
errors in one clause (the ``vmehil`` command line catches the four roots). An error that is also a
builtin kind keeps it by multiple inheritance (``class FooError(ServoError, ValueError)``), so
``except ValueError`` still works where callers rely on it. tests/test_exception_roots.py checks
that no exception class of the package stands outside this root.
"""

__all__ = ["ServoError"]


class ServoError(Exception):
    """Any typed error of the controller (servo)."""
