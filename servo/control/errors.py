"""Typed errors of the control layer.

One gain error family for the whole project::

    ControlError (ValueError)
    └── GainError               a gain (or other per-joint control parameter) is invalid
        ├── GainSyntaxError     gain text (``kp=100,kpi=5000``) that does not parse: names the token
        └── GainRejected        servo.gain_guard refused a gain set (invalid value or unstable loop)
"""

from __future__ import annotations

import numbers
from typing import Any

from servo.errors import ServoError


def _shown(value: Any) -> str:
    """A value for a message: a number as a plain float (not ``np.float64(…)``), else its repr."""
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return repr(float(value))
    return repr(value)


class ControlError(ServoError, ValueError):
    """Base class for control-layer errors (bad gains, bad controller composition)."""


class GainError(ControlError):
    """A gain (or another per-joint control parameter) is not finite / not non-negative / wrong shape.

    ``name`` is the parameter (``"kp"``), ``joint`` the joint index (``None`` when the whole value is
    wrong, e.g. the shape), ``value`` the offending value, ``expected`` what would be accepted and
    ``problem`` (optional) what is wrong with it, e.g. ``"is negative"``. Subclasses pass their own
    ``message``.
    """

    def __init__(self, name: str, value: Any, expected: str, joint: int | None = None,
                 problem: str | None = None, *, message: str | None = None) -> None:
        self.name = name
        self.value = value
        self.joint = joint
        self.expected = expected
        self.problem = problem
        where = f"{name}[{joint}]" if joint is not None else name
        what = f" {problem}" if problem else ""
        super().__init__(message or f"gain {where} = {_shown(value)}{what}: expected {expected}; nothing was changed, "
                                    "fix the value and retry")


class GainSyntaxError(GainError):
    """Gain text that does not parse (:func:`servo.control.gains.parse_gains`).

    ``token`` is the offending ``name=value`` item as written (whitespace around ``=`` removed),
    ``text`` the whole text, ``problem`` what is wrong with the token; ``name``/``value`` are the
    token's name and value text where it has them; ``what`` names the text in the message (e.g.
    ``"--gains"``).
    """

    def __init__(self, token: str, text: str, problem: str, name: str = "", value: str = "",
                 what: str = "gains") -> None:
        self.token = token
        self.text = text
        super().__init__(name, value, "name=value", problem=problem, message=(
            f"{what} {text!r}: {token!r} {problem}; write name=value items separated by commas or spaces, "
            "e.g. kp=100,kpi=5000,kv=50,kvi=1000"))


class GainRejected(GainError):
    """:mod:`servo.gain_guard` refused a gain set; nothing was changed.

    ``name`` is the gain (or ``"joint"``, ``"period"``, ``"delay"``, or the shown change for a
    loop-level refusal), ``joint`` the joint index (None: the request as a whole), ``value`` the
    offending value (None for a loop-level refusal), ``reason`` a short human explanation with what
    to do instead, ``kind`` ``"invalid"`` (a value no gain may have: not a number, not finite,
    negative, subnormal, beyond the limits) or ``"unstable"`` (valid values, but the sampled loop
    would be unstable or marginal).
    """

    def __init__(self, name: str, value: Any, reason: str, joint: int | None = None,
                 kind: str = "invalid") -> None:
        self.reason = reason
        self.kind = kind
        what = name if value is None else f"{name}={_shown(value)}"
        where = f" on joint index {joint}" if joint is not None else ""
        super().__init__(name, value, reason, joint,
                         message=f"gain change {what}{where} rejected: {reason}; nothing was changed")
