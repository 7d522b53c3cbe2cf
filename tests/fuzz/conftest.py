"""The fuzz harnesses' settings: every ``@given`` test under ``tests/fuzz`` runs with the profile
``fuzz-short`` (the suite: :data:`~tests.fuzz.harness.SHORT_EXAMPLES` examples, derandomized)
or, given ``--fuzz-n N`` (``python -m tests.fuzz``), ``fuzz-long`` (N examples, random, seeded by
``--hypothesis-seed``), and each example is bounded in time (``--fuzz-timeout-s``)."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, settings

from tests.fuzz.harness import SHORT_EXAMPLES, SUITE_TIMEOUT_S, bounded

_SUPPRESS = (HealthCheck.too_slow, HealthCheck.function_scoped_fixture, HealthCheck.filter_too_much,
             HealthCheck.data_too_large)
settings.register_profile("fuzz-short", max_examples=SHORT_EXAMPLES, derandomize=True, deadline=None,
                          print_blob=True, suppress_health_check=_SUPPRESS)


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("fuzz", "fuzz harnesses (tests/fuzz)")
    g.addoption("--fuzz-n", type=int, default=None, help="examples per harness (the long run); default: the short run")
    g.addoption("--fuzz-timeout-s", type=float, default=None,
                help=f"per-example bound, s (default {SUITE_TIMEOUT_S:g})")


def _harness_name(item: pytest.Item) -> str:
    return item.nodeid.split("[", 1)[0]


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    n = config.getoption("--fuzz-n", default=None)
    if n is not None:
        settings.register_profile("fuzz-long", max_examples=n, derandomize=False, deadline=None, print_blob=True,
                                  suppress_health_check=_SUPPRESS)
    profile = settings.get_profile("fuzz-long" if n is not None else "fuzz-short")
    timeout_s = config.getoption("--fuzz-timeout-s", default=None) or SUITE_TIMEOUT_S
    for item in items:
        fn: Any = getattr(item, "obj", None)
        if "tests/fuzz/" not in item.nodeid or not getattr(fn, "is_hypothesis_test", False):
            continue
        if getattr(fn, "_fuzz_bounded", False):  # one function, several parametrized items
            continue
        own = fn._hypothesis_internal_use_settings
        fn._hypothesis_internal_use_settings = settings(
            own, max_examples=profile.max_examples, derandomize=profile.derandomize, deadline=None,
            suppress_health_check=tuple(set(own.suppress_health_check) | set(_SUPPRESS)))
        fn.hypothesis.inner_test = bounded(_harness_name(item), fn.hypothesis.inner_test, timeout_s)
        fn._fuzz_bounded = True
