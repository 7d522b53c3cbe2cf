"""Plug-in points: a package's table of built-in things plus what installed distributions declare.

A plug-in point (board types, control objects, calibration procedures) is a :class:`PluginTable`:
the owning package's plain table of built-ins, and the Python entry points of one group that any
installed distribution declares in its ``pyproject.toml``::

    [project.entry-points."vmehil.board_types"]
    acme-adc = "acme_boards:adc_factory"

so a third-party package adds one without editing ours. Nothing registers itself on import: the
entry points are read from the installed metadata on the first look-up that needs them, and an
entry point's object is imported on its first use. It lives in ``hal`` because ``hal`` imports
nothing of ours, so every package may use it (see docs/architecture.md, "Plug-in points").
"""

from __future__ import annotations

import threading
import warnings
from collections.abc import Callable, Iterator, Mapping
from importlib.metadata import EntryPoint, entry_points
from typing import Any, Generic, TypeVar

from hal.errors import HalError

T = TypeVar("T")


class PluginError(HalError, ValueError):
    """An entry point that cannot be used: it fails to import, or is not what the group expects.
    A ValueError, as a bad value in a config file is: the command line reports it in one line."""


class UnknownPluginError(PluginError, KeyError):
    """A name that is neither built in nor declared by an installed distribution; lists the known names."""

    def __init__(self, what: str, name: str, known: list[str]) -> None:
        self.what, self.name, self.known = what, name, known
        super().__init__(f"unknown {what} {name!r}; known: {', '.join(known) or '(none)'}")

    def __str__(self) -> str:  # KeyError's own str() would quote the message
        return str(self.args[0])


class PluginShadowWarning(UserWarning):
    """An entry point uses the name of a built-in; the built-in is kept."""


def _origin(ep: EntryPoint) -> str:
    dist = getattr(ep, "dist", None)
    return f"{ep.value!r} of {dist.name if dist is not None else 'an unnamed distribution'}"


class PluginTable(Mapping[str, T], Generic[T]):
    """``name → T``: the ``builtin`` table, then the entry points of ``group``.

    ``what`` names one item in messages ("board type"). ``validate(name, obj)`` checks an
    entry point's loaded object and returns it as a ``T`` (raise ``TypeError``/``ValueError`` to
    refuse it). Built-ins win: installing a package cannot change what a built-in name means.
    A name two distributions declare is refused when it is used.
    """

    def __init__(self, group: str, what: str, builtin: Mapping[str, T],
                 validate: Callable[[str, Any], T] | None = None) -> None:
        self.group = group
        self.what = what
        self._builtin = builtin  # the owning package's table stays the one source of the built-ins
        self._validate = validate
        self._lock = threading.Lock()
        self._declared: dict[str, list[EntryPoint]] | None = None
        self._loaded: dict[str, T] = {}

    def _entry_points(self) -> dict[str, list[EntryPoint]]:
        with self._lock:
            if self._declared is None:
                declared: dict[str, list[EntryPoint]] = {}
                for ep in entry_points(group=self.group):
                    if ep.name in self._builtin:
                        warnings.warn(f"{self.what} {ep.name!r} ({_origin(ep)}) is built in; the entry point "
                                      f"is ignored", PluginShadowWarning, stacklevel=2)
                        continue
                    same = declared.setdefault(ep.name, [])
                    if all(ep.value != other.value for other in same):
                        same.append(ep)
                self._declared = declared
            return self._declared

    def _load(self, name: str, candidates: list[EntryPoint]) -> T:
        if len(candidates) > 1:
            raise PluginError(f"{self.what} {name!r} is declared by several installed distributions: "
                              + ", ".join(_origin(ep) for ep in candidates))
        ep = candidates[0]
        try:
            obj = ep.load()
            return self._validate(name, obj) if self._validate is not None else obj
        except Exception as e:
            raise PluginError(f"{self.what} {name!r} (entry point {_origin(ep)} in group {self.group!r}) "
                              f"cannot be used: {type(e).__name__}: {e}") from e

    def __getitem__(self, name: str) -> T:
        # Built-ins never touch the installed metadata: a hot path (a controller built per sweep
        # point) stays as fast as a dict look-up.
        if name in self._builtin:
            return self._builtin[name]
        if name in self._loaded:
            return self._loaded[name]
        candidates = self._entry_points().get(name)
        if not candidates:
            raise UnknownPluginError(self.what, name, self.names())
        obj = self._load(name, candidates)
        self._loaded[name] = obj
        return obj

    def __contains__(self, name: object) -> bool:
        return name in self._builtin or (isinstance(name, str) and name in self._entry_points())

    def __iter__(self) -> Iterator[str]:
        yield from self._builtin
        yield from self._entry_points()

    def __len__(self) -> int:
        return len(self._builtin) + len(self._entry_points())

    def names(self) -> list[str]:
        """Every known name, sorted (for messages and ``--help``)."""
        return sorted(self)

    def refresh(self) -> None:
        """Read the installed entry points again on the next look-up (after installing a package
        in a running process, and in tests)."""
        with self._lock:
            self._declared = None
            self._loaded.clear()
