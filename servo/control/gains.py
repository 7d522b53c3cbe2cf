"""The JPL servo gains: their names, units, defaults, the :class:`Gains` type and their text form.

Normalized units (every joint looks like the unit double integrator θ'' = a, a in rad/s², see
:mod:`servo.control.normalize`), per joint::

    a = Kp·e + Kpi·∫e dt + Kv·ė + KvI·∫ė dt        e rad, ė rad/s

    kp   Kp    1/s²   position gain
    kpi  Kpi   1/s³   position-integral gain
    kv   Kv    1/s    velocity gain
    kvi  KvI   1/s²   velocity-integral gain

A valid gain is a finite number ≥ 0 (the law subtracts the feedback itself). Whether a gain set may
be *used* — upper limits, stability of the sampled loop — is :mod:`servo.gain_guard`'s call.

Text form (``--gains``, rig overrides, sweeps): :func:`parse_gains` / :func:`format_gains`::

    kp=100,kpi=5000,kv=50,kvi=1000      commas,
    kp=100 kpi=5000                     or whitespace between items (any mix, repeated, trailing);
    kp = 100, KV=50                     whitespace around "=" is ignored, names are case-insensitive;
    kp=1e2                              values are Python float literals;
    kp=1,kp=2                           a repeated gain: the last one counts (as the old parsers did).

``;`` is *not* a separator between gains: it separates the values of a sweep grid axis
(``kvi=800;1000``, :func:`servo.control.gains.gain_items` hands such value text to the grid parser),
so in a gain list it is an error that names the token.
"""

from __future__ import annotations

import math
import numbers
import re
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

import numpy as np

from servo.control.errors import GainError, GainSyntaxError
from servo.control.normalize import per_joint

#: The gain names, in the order every table, CSV and JSON lists them.
GAIN_NAMES: tuple[str, ...] = ("kp", "kpi", "kv", "kvi")
#: SI units of the normalized gains.
GAIN_UNITS: dict[str, str] = {"kp": "1/s²", "kpi": "1/s³", "kv": "1/s", "kvi": "1/s²"}
#: What each gain is (for parameter tables and reports).
GAIN_DESCRIPTIONS: dict[str, str] = {"kp": "position gain Kp", "kpi": "position integral gain Kpi",
                                     "kv": "velocity gain Kv", "kvi": "velocity integral gain KvI"}
#: The JPL paper's gains (Kv=50, KvI=1000, Kp=100, Kpi=5000): the defaults everywhere.
DEFAULT_GAINS: dict[str, float] = {"kp": 100.0, "kpi": 5000.0, "kv": 50.0, "kvi": 1000.0}

V = TypeVar("V", float, np.ndarray)

_EXPECTED = "a finite number ≥ 0 (the law subtracts the feedback itself)"


def gain_value_problem(value: Any) -> str | None:
    """What makes ``value`` no gain at all (``"is not a number"``, ``"is not finite"``,
    ``"is negative"``), or None when it is a finite number ≥ 0. The one rule, shared by
    :class:`Gains` and :mod:`servo.gain_guard`."""
    if isinstance(value, np.ndarray) and value.ndim == 0:
        value = value.item()
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return "is not a number"
    v = float(value)
    if not math.isfinite(v):
        return "is not finite"
    if v < 0.0:
        return "is negative"
    return None


def _check_names(m: Mapping[str, Any]) -> None:
    unknown = sorted(set(m) - set(GAIN_NAMES))
    if unknown:
        raise GainError(unknown[0], m[unknown[0]], f"one of the gains {', '.join(GAIN_NAMES)}",
                        problem="is not a gain name")


def _scalar(name: str, value: Any) -> float:
    problem = gain_value_problem(value)
    if problem is not None:
        raise GainError(name, value, _EXPECTED, problem=problem)
    return float(value) + 0.0  # (+ 0.0 turns −0.0 into 0.0)


@dataclass(frozen=True, eq=False)
class Gains(Generic[V]):
    """The four gains of the normalized loop (units in the module docstring).

    One joint's set: each field a float — ``Gains(kp=100, kpi=5000, kv=50, kvi=1000)``; hashable,
    what the analysis, the guard and the sweeps use. A set for n joints: each field a read-only
    float64 array of length n — :meth:`make`, what :class:`servo.control.law.PidLaw` holds;
    :meth:`joint` takes one joint's set out of it. Values are validated on construction
    (:class:`GainError` naming the gain and joint).
    """

    kp: V
    kpi: V
    kv: V
    kvi: V

    def __post_init__(self) -> None:
        values = [getattr(self, k) for k in GAIN_NAMES]
        shaped = [v for v in values if np.ndim(v) != 0]
        if not shaped:
            for k, v in zip(GAIN_NAMES, values, strict=True):
                object.__setattr__(self, k, _scalar(k, v))
            return
        n = len(shaped[0])
        for k, v in zip(GAIN_NAMES, values, strict=True):
            arr = per_joint(k, v, n)
            arr.setflags(write=False)  # a frozen set: change gains through PidLaw.set_gains
            object.__setattr__(self, k, arr)

    # ---- construction ------------------------------------------------------------------------
    @classmethod
    def paper(cls) -> Gains[float]:
        """The JPL paper's gains, one joint: Kp=100, Kpi=5000, Kv=50, KvI=1000."""
        return Gains(**DEFAULT_GAINS)

    @classmethod
    def make(cls, n: int, kp: float | np.ndarray | list[float] = DEFAULT_GAINS["kp"],
             kpi: float | np.ndarray | list[float] = DEFAULT_GAINS["kpi"],
             kv: float | np.ndarray | list[float] = DEFAULT_GAINS["kv"],
             kvi: float | np.ndarray | list[float] = DEFAULT_GAINS["kvi"]) -> Gains[np.ndarray]:
        """Validated gains for ``n`` joints (scalars broadcast); raises :class:`GainError`."""
        return Gains(per_joint("kp", kp, n), per_joint("kpi", kpi, n), per_joint("kv", kv, n),
                     per_joint("kvi", kvi, n))

    @classmethod
    def from_mapping(cls, m: Mapping[str, Any], base: Gains[float] | None = None) -> Gains[float]:
        """One joint's set from a ``{kp: .., kpi: .., kv: .., kvi: ..}`` mapping (any subset, names
        case-insensitive); missing gains come from ``base`` (default: the paper's)."""
        base = base if base is not None else cls.paper()
        return base.replace(**{str(k).strip().lower(): v for k, v in m.items()})

    def replace(self, **changes: Any) -> Gains[V]:
        """A copy with some gains changed (validated; an unknown name is a :class:`GainError`)."""
        _check_names(changes)
        return Gains(**{k: changes.get(k, getattr(self, k)) for k in GAIN_NAMES})

    # ---- views ----------------------------------------------------------------------------------
    @property
    def n(self) -> int | None:
        """Number of joints of a per-joint set; None for one joint's set (floats)."""
        return None if isinstance(self.kp, float) else int(self.kp.shape[0])

    def joint(self, j: int) -> Gains[float]:
        """Joint ``j``'s set (0-based) of a per-joint set; one joint's set is returned as is."""
        if self.n is None:
            return self  # type: ignore[return-value]
        return Gains(**{k: float(getattr(self, k)[j]) for k in GAIN_NAMES})

    def broadcast(self, n: int) -> Gains[np.ndarray]:
        """This set for ``n`` joints: one joint's set repeated, or a per-joint set checked for n."""
        if self.n is None:
            return Gains.make(n, **self.as_dict())
        if self.n != n:
            raise GainError("gains", self.n, f"gains for {n} joints")
        return self  # type: ignore[return-value]

    def as_dict(self) -> dict[str, Any]:
        """``{kp: float, ...}`` for one joint; ``{kp: [float per joint], ...}`` for a per-joint set."""
        if self.n is None:
            return {k: getattr(self, k) for k in GAIN_NAMES}
        return {k: [float(x) for x in getattr(self, k)] for k in GAIN_NAMES}

    def _key(self) -> tuple[Any, ...]:
        return tuple(getattr(self, k) if self.n is None else tuple(getattr(self, k).tolist()) for k in GAIN_NAMES)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Gains) and self._key() == other._key()

    def __hash__(self) -> int:
        return hash(self._key())

    def __str__(self) -> str:
        if self.n is None:
            return ", ".join(f"{k}={getattr(self, k):g}" for k in GAIN_NAMES)
        return ", ".join(f"{k}=[{', '.join(f'{x:g}' for x in getattr(self, k))}]" for k in GAIN_NAMES)


# ---- text form ------------------------------------------------------------------------------------
_SPACE_AROUND = re.compile(r"\s*([=:;])\s*")  # "kp = 100", a grid's "80 : 140 : 4" and "800; 1000"
_SEPARATORS = re.compile(r"[,\s]+")


def gain_items(text: str | None, what: str = "gains") -> list[tuple[str, str, str]]:
    """The ``name=value`` items of ``text``, in order, as (gain name, value text, token).

    Names are checked against :data:`GAIN_NAMES` (lower-cased); values are handed back as text (a
    sweep grid parses its ``start:stop:count`` and ``v1;v2`` values itself). Raises
    :class:`GainSyntaxError` naming the first bad token (``what``: where the text came from, e.g.
    ``"--gains"``, for the message); never anything else.
    """
    if text is None:
        return []
    normalized = _SPACE_AROUND.sub(r"\1", text)
    items = []
    for token in _SEPARATORS.split(normalized):
        if not token:
            continue
        name, sep, value = token.partition("=")
        if not sep:
            raise GainSyntaxError(token, text, "is malformed: no '=' (write name=value)", what=what)
        if not name:
            raise GainSyntaxError(token, text, "is malformed: no gain name before '='", value=value, what=what)
        key = name.lower()
        if key not in GAIN_NAMES:
            raise GainSyntaxError(token, text, f"names an unknown gain {name!r}; known: {', '.join(GAIN_NAMES)}",
                                  name, value, what)
        if not value:
            raise GainSyntaxError(token, text, "is malformed: no value after '='", key, what=what)
        items.append((key, value, token))
    if not items and normalized.strip():  # ",,,": separators and nothing else is no gain set
        raise GainSyntaxError(text.strip(), text, "names no gain (write name=value, e.g. kp=100)", what=what)
    return items


def parse_gains(text: str | None, what: str = "gains") -> dict[str, float]:
    """``"kp=100,kpi=5000"`` → ``{"kp": 100.0, "kpi": 5000.0}``: the gains the text gives (any subset).

    Pure syntax (grammar in the module docstring): a value is any float literal, including
    ``nan``, ``inf`` or a negative number — :mod:`servo.gain_guard` judges values, with a reason.
    ``None`` or blank text gives ``{}``. Raises :class:`GainSyntaxError` naming the token (and
    ``what`` the text is, e.g. ``"--gains"``), nothing else.
    """
    out: dict[str, float] = {}
    for key, value, token in gain_items(text, what):
        try:
            out[key] = float(value)
        except ValueError:
            raise GainSyntaxError(token, text or "", f"has a value {value!r} that is not a number", key,
                                  value, what) from None
    return out


def format_gains(gains: Mapping[str, float] | Gains[float]) -> str:
    """The text :func:`parse_gains` reads back exactly: ``kp=100.0,kpi=5000.0`` (in
    :data:`GAIN_NAMES` order, shortest round-trip float repr)."""
    m = gains.as_dict() if isinstance(gains, Gains) else dict(gains)
    _check_names(m)
    return ",".join(f"{k}={float(m[k])!r}" for k in GAIN_NAMES if k in m)
