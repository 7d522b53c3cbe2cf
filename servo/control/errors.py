"""Typed errors of the control layer."""

from __future__ import annotations

from typing import Any


class ControlError(ValueError):
    """Base class for control-layer errors (bad gains, bad controller composition)."""


class GainError(ControlError):
    """A gain (or another per-joint control parameter) is not finite / not non-negative / wrong shape.

    ``name`` is the parameter (``"kp"``), ``joint`` the joint index (``None`` when the whole value is
    wrong, e.g. the shape), ``value`` the offending value.
    """

    def __init__(self, name: str, value: Any, expected: str, joint: int | None = None) -> None:
        self.name = name
        self.value = value
        self.joint = joint
        self.expected = expected
        where = f"{name}[{joint}]" if joint is not None else name
        super().__init__(f"gain {where} = {value!r}: expected {expected}; nothing was changed, fix the value and retry")
