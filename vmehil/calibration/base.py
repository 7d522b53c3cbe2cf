"""What every calibration procedure shares: the context it runs in, its result, its table entry.

A procedure is a class with ``name``, ``version``, ``title`` and ``run(ctx) -> ProcedureResult``,
named in :data:`vmehil.calibration.procedures.PROCEDURES` by a :class:`ProcedureSpec`. It talks
to the rig only through the context:

* ``ctx.adc(board)`` / ``ctx.dac(board)`` / ``ctx.quad(board)``: drivers opened on ``ctx.bus``
  from the rig's ``[crate]`` (raw or with the calibration in force);
* ``ctx.positioner()``: moves joints with the servo loop and lets time pass (emulated rigs:
  :class:`vmehil.rig_setup.emulated_calibration.EmulatedPositioner`);
* ``ctx.reference_angle(j)``: the joint's angle from the reference — the fixture in ``--auto``
  mode, the operator (stdin prompt) otherwise;
* ``ctx.say`` / ``ctx.progress``: what it is doing, and how far it got.

It never touches emulator internals, so the same procedure calibrates real boards.
Results are returned, not written: :func:`~vmehil.calibration.procedure_runner.run_procedures`
writes the store once, after success.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

from hal.adc_dac.adc import AdcDriver
from hal.adc_dac.dac import DacDriver
from hal.board_types import BOARD_TYPES, board_role
from hal.vme.bus import VmeBus
from servo.io import JointIO
from servo.rig import RigSpec
from vmehil.calibration.store import CalibrationStore, rig_boards
from vmehil.errors import VmehilError


class CalibrationAbort(VmehilError, RuntimeError):
    """A procedure cannot go on (missing wiring, operator abort, unusable data); nothing is written."""


@dataclass
class Check:
    """One row of the results table: a measured figure against its tolerance.

    ``kind`` is ``"max"`` (pass if ``|value| <= limit``), ``"min"`` (``value >= limit``) or
    ``"bool"`` (pass if ``value`` is true; ``limit`` ignored).
    """

    item: str
    value: float
    unit: str
    limit: float
    kind: str = "max"
    note: str = ""

    @property
    def passed(self) -> bool:
        if self.kind == "bool":
            return bool(self.value)
        if not math.isfinite(self.value):
            return False
        return abs(self.value) <= self.limit if self.kind == "max" else self.value >= self.limit

    def as_dict(self) -> dict[str, Any]:
        return {"item": self.item, "value": self.value, "unit": self.unit, "limit": self.limit, "kind": self.kind,
                "passed": self.passed, "note": self.note}


@dataclass
class ProcedureResult:
    """What a procedure found: checks, the store entries to write, JSON data."""

    procedure: str
    version: int
    checks: list[Check] = field(default_factory=list)
    update: CalibrationStore | None = None
    data: dict[str, Any] = field(default_factory=dict)
    skipped: list[str] = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def as_dict(self) -> dict[str, Any]:
        return {"procedure": self.procedure, "version": self.version, "passed": self.passed,
                "checks": [c.as_dict() for c in self.checks], "skipped": self.skipped, **self.data}


class Fixture(Protocol):
    """A precise angle reference (a calibration fixture, or in the emulator the joint's true angle)."""

    def joint_angle(self, joint: int) -> float:
        """Angle of joint ``joint`` (0-based) in rad."""
        ...


TickHook = Callable[[], None]


class Positioner(Protocol):
    """Moves joints with the servo loop; lets time pass. All angles in rad, times in s."""

    period_s: float
    io: JointIO  #: the drivers the loop uses (calibration in force applied)

    def move_to(self, targets: dict[int, float], *, settle_s: float = 1.0, on_tick: TickHook | None = None,
                speed_rad_s: float | Mapping[int, float] | None = None) -> None:
        """Move the given joints (0-based) to ``targets`` with the servo loop (at most
        ``speed_rad_s``: one speed for every joint or one per joint; default the rig's limit),
        then hold ``settle_s``; others hold."""
        ...

    def hold(self, seconds: float, *, on_tick: TickHook | None = None) -> None:
        """Keep the servo on for ``seconds``; ``on_tick`` runs at each servo tick right after the
        sensors were sampled (before the loop computes)."""
        ...

    def override_command(self, joint: int, volts: float | None) -> None:
        """Replace the loop's amplifier command of ``joint`` by ``volts`` (calibrated DAC volts)
        for the next tick only (``None``: no override)."""
        ...

    def position(self, joint: int) -> float:
        """The loop's measured position of ``joint`` (rad)."""
        ...

    def faulted(self) -> str | None:
        """Why the loop stopped, or ``None``."""
        ...


def _console_progress(what: str, i: int, n: int) -> None:  # pragma: no cover - display only
    pass


@dataclass
class CalibrationContext:
    """Everything a procedure may use. See the module docstring."""

    rig: RigSpec
    bus: VmeBus
    store: CalibrationStore
    auto: bool = False
    fixture: Fixture | None = None
    positioner_factory: Callable[[CalibrationStore], Positioner] | None = None
    joints: list[int] | None = None
    prompt: Callable[[str], str] = input
    say: Callable[[str], None] = print
    progress: Callable[[str, int, int], None] = _console_progress
    options: dict[str, Any] = field(default_factory=dict)
    _positioner: Positioner | None = None

    # --- boards -----------------------------------------------------------------------------
    def boards_of(self, kind: str) -> list[str]:
        """The boards of role ``kind`` (hal.board_types: ``"adc"`` is every ADC, whatever its type)."""
        return [b.name for b in rig_boards(self.rig).values() if board_role(b.type) == kind]

    def _driver(self, board: str, kind: str, calibrated: bool) -> Any:
        """The driver of ``board``'s own type (which must be of role ``kind``), opened on the bus
        with the calibration in force or raw (identity)."""
        ident = rig_boards(self.rig).get(board)
        if ident is None or board_role(ident.type) != kind:
            raise CalibrationAbort(f"rig {self.rig.name}: no {kind} board named {board!r} in [crate]")
        cal = self.store.board_calibration(board) if calibrated else None
        factory = BOARD_TYPES[ident.type].load_driver()
        return factory(self.bus, ident.base, space=ident.space, calibration=cal)

    def adc(self, board: str, *, calibrated: bool = True) -> AdcDriver:
        """An ADC driver on ``board`` (its type's: the reference ``AdcDriver`` or another of the
        role's, with the same reading interface): with the calibration in force, or raw (identity)."""
        return self._driver(board, "adc", calibrated)  # type: ignore[no-any-return]

    def dac(self, board: str, *, calibrated: bool = True) -> DacDriver:
        """A DAC driver on ``board`` (its type's), as :meth:`adc`."""
        return self._driver(board, "dac", calibrated)  # type: ignore[no-any-return]

    # --- joints -----------------------------------------------------------------------------
    def selected_joints(self) -> list[int]:
        return list(range(self.rig.n_joints)) if self.joints is None else list(self.joints)

    def positioner(self) -> Positioner:
        """The servo-loop positioner, built with the calibration in force now."""
        if self._positioner is None:
            if self.positioner_factory is None:
                raise CalibrationAbort("this procedure moves joints, but no servo loop is available for this rig "
                                       "(the emulated plant or the real arm must be connected)")
            self._positioner = self.positioner_factory(self.store)
        return self._positioner

    def refresh_positioner(self) -> None:
        """Drop the positioner so the next one is built with the (updated) calibration in force."""
        self._positioner = None

    def reference_angle(self, joint: int, nominal_rad: float) -> float:
        """The joint's angle (rad) from the reference: the fixture with ``--auto``, else the operator."""
        if self.auto:
            if self.fixture is None:
                raise CalibrationAbort("--auto needs the rig's reference fixture, and this rig has none")
            return float(self.fixture.joint_angle(joint))
        name = self.rig.joints[joint].name
        while True:
            text = self.prompt(
                f"  {name}: the loop holds it near {math.degrees(nominal_rad):+.2f}°. Measure the joint angle with "
                f"the level/protractor and type it in degrees (Enter = {math.degrees(nominal_rad):+.2f}, q = abort): ")
            text = text.strip()
            if text.lower() in ("q", "quit", "abort"):
                raise CalibrationAbort("aborted by the operator; nothing written")
            if not text:
                return nominal_rad
            try:
                return math.radians(float(text))
            except ValueError:
                self.say(f"  {text!r} is not a number of degrees; try again")


class Procedure(Protocol):
    name: str
    version: int
    title: str

    def run(self, ctx: CalibrationContext) -> ProcedureResult: ...


@dataclass(frozen=True)
class ProcedureSpec:
    """A procedure in the table: its factory, its place in ``calibrate all`` (lower runs first) and
    its line in ``--help``. An entry point of group ``vmehil.calibration_procedures`` names one."""

    name: str
    factory: Callable[[], Procedure]
    order: int
    help: str
    in_all: bool = True
    #: the procedure asks the operator (angles typed at a prompt) unless ``--auto``: without a
    #: terminal it is refused before anything is built, not at its first prompt
    asks_operator: bool = False
