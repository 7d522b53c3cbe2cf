"""Named fault injection shared by every board emulator (and the plant, the CAN plant node and
the vision system).

Each emulator declares the faults it supports (name → one-line description, parameters first)
in a ``FAULTS`` class attribute; a class inherits its bases' faults (every board has
``removed``). Tests and ``vmehil run --fault`` scenarios switch them on with parameters and off
again.
"""

from __future__ import annotations

from typing import Any, ClassVar

from emulators.errors import EmulatorError


class UnknownFaultError(EmulatorError, KeyError):
    """The board has no fault of that name."""


class FaultInjectable:
    """Mixin: ``inject(name, **params)``, ``clear_fault(name)``, ``active_faults``."""

    FAULTS: ClassVar[dict[str, str]] = {}
    #: True while any fault is on. The hot paths (a bus cycle, an ADC sample) test this one
    #: attribute first, so "no fault armed" costs an attribute read, not a dict lookup.
    faulted: bool = False

    @classmethod
    def known_faults(cls) -> dict[str, str]:
        """Every fault of this class: its own ``FAULTS`` and those of its bases (name → description)."""
        out: dict[str, str] = {}
        for klass in reversed(cls.__mro__):
            out.update(klass.__dict__.get("FAULTS", {}))
        return out

    def _faults(self) -> dict[str, dict[str, Any]]:
        f = self.__dict__.get("_active_faults")
        if f is None:
            f = self.__dict__["_active_faults"] = {}
        return f

    def _set_faulted(self) -> None:
        self.faulted = bool(self.__dict__.get("_active_faults"))

    def inject(self, name: str, **params: Any) -> None:
        """Switch fault ``name`` on with its parameters (see the board's ``FAULTS``)."""
        known_faults = self.known_faults()
        if name not in known_faults:
            known = ", ".join(sorted(known_faults)) or "none"
            raise UnknownFaultError(f"{type(self).__name__} has no fault {name!r} (known: {known})")
        self._faults()[name] = dict(params)
        self.faulted = True
        self._fault_changed(name)

    def clear_fault(self, name: str | None = None) -> None:
        """Switch one fault (or all, with ``None``) off."""
        if name is None:
            names = list(self._faults())
            self._faults().clear()
            self._set_faulted()
            for n in names:
                self._fault_changed(n)
        else:
            self._faults().pop(name, None)
            self._set_faulted()
            self._fault_changed(name)

    def fault(self, name: str) -> dict[str, Any] | None:
        """The parameters of an active fault, or ``None`` if it is off."""
        if not self.faulted:
            return None
        return self._faults().get(name)

    @property
    def active_faults(self) -> dict[str, dict[str, Any]]:
        return dict(self._faults())

    def _fault_changed(self, name: str) -> None:
        """Hook for boards that must react when a fault toggles."""
