"""Fuzz harnesses (hypothesis ``@given`` tests): a short run in the test suite, a long run with
``python -m tests.fuzz --n 100000`` (see docs/fuzzing.md)."""
