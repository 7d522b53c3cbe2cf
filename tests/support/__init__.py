"""Helpers shared by the tests: :mod:`tests.support.fakes` (every fake: the double integrator and
the small servo loops over it), :mod:`tests.support.calib_bench` (the calibration bench) and
:mod:`tests.support.console` (driving a console from a test)."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
"""The repository root (docs/, the packages, pyproject.toml)."""
