"""The signal catalog: every signal a trace can record, by dotted name, and the SPEC that chooses.

A name is ``<group>.<leaf>``: the group is everything before the last dot (``j1``, ``drv.j1``,
``net.j1``, ``net.j1.encoder``, ``truth.j1``, ``irq``, ``bus``) and is one MCAP channel; the leaf
carries its unit as a suffix where it has one. A rig's catalog is made from what the rig has
(its joints, its nets, an emulated crate's bus and plant): :func:`build_catalog`.

SPEC (``--trace``): comma-separated items, each a name or a shell-style pattern (``*``, ``?``,
``[...]``; ``*`` also matches dots), matched against every name; an item that is exactly a group's
name means the whole group; an item starting with ``-`` removes what it matches from what the
items before it chose (``*,-bus.*``). ``*`` is everything. An item that matches nothing is an
error naming the nearest names. docs/scope.md lists the names.
"""

from __future__ import annotations

import difflib
import fnmatch
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from vmehil.errors import VmehilError

__all__ = ["BUS", "CONTROLLER", "DRIVER", "Catalog", "Signal", "TraceSpecError", "build_catalog"]


class TraceSpecError(VmehilError, ValueError):
    """A ``--trace`` SPEC that chooses nothing, or an item of it that matches no signal."""


@dataclass(frozen=True)
class Signal:
    """One traceable signal. ``kind``: ``f`` a number (NaN: no value), ``i`` an integer, ``b`` a
    level; ``per_tick``: one value per servo tick (False: an event stream, the bus cycles)."""

    name: str
    kind: str
    unit: str
    doc: str
    per_tick: bool = True

    @property
    def group(self) -> str:
        return self.name.rpartition(".")[0]

    @property
    def leaf(self) -> str:
        return self.name.rpartition(".")[2]

    @property
    def digital(self) -> bool:
        """A level or a count: what a VCD carries (numbers with a fraction stay out of it)."""
        return self.kind in ("b", "i")


# (leaf, kind, unit, what) of each joint's groups --------------------------------------------
#: the controller's view of joint J (group ``J``): the loop's per-tick record and the law's state
CONTROLLER: tuple[tuple[str, str, str, str], ...] = (
    ("target_rad", "f", "rad", "the trajectory's position (theta_d)"),
    ("target_rad_s", "f", "rad/s", "the trajectory's velocity (omega_d)"),
    ("position_rad", "f", "rad", "the measured position the law used (pot or encoder)"),
    ("velocity_rad_s", "f", "rad/s", "the measured velocity the law used (tach or encoder)"),
    ("error_rad", "f", "rad", "target - position"),
    ("torque_nm", "f", "N·m", "the law's torque command"),
    ("current_cmd_a", "f", "A", "the current commanded to the amplifier (after the limit)"),
    ("current_a", "f", "A", "the current monitor's reading"),
    ("integral_e", "f", "rad·s", "the law's integrator of the position error"),
    ("integral_edot_rad", "f", "rad", "the law's integrator of the velocity error"),
    ("kp_eff", "f", "1/s²", "the position gain in force (boosted while switched off)"),
    ("integrating", "b", "", "switch-off state: the integrators are fed"),
    ("stop_state", "i", "", "0 servoing, 1 decelerating (category-1 stop), 2 holding (category 2), "
                            "3 stopped (power off)"),
)
#: the drivers' values of joint J (group ``drv.J``), as the last read and write left them
DRIVER: tuple[tuple[str, str, str, str], ...] = (
    ("pot_v", "f", "V", "the pot's calibrated ADC volts"),
    ("enc_counts", "i", "counts", "the decoder's unwrapped count (mode units)"),
    ("enc_illegal", "b", "", "the decoder flagged an illegal transition since the last read"),
    ("amp_fault", "b", "", "the amplifier's fault line as the PIO read it"),
    ("dac_v", "f", "V", "the DAC volts last commanded (linear amplifiers)"),
    ("brake_released", "b", "", "the holding brake's line: released"),
)
#: the plant's truth of joint J (group ``truth.J``): leaf, the plant's key, kind, unit, what
TRUTH: tuple[tuple[str, str, str, str, str], ...] = (
    ("theta_rad", "theta_joint", "f", "rad", "the joint's true angle"),
    ("omega_rad_s", "omega_joint", "f", "rad/s", "the joint's true velocity"),
    ("theta_motor_rad", "theta_motor", "f", "rad", "the motor's angle"),
    ("omega_motor_rad_s", "omega_motor", "f", "rad/s", "the motor's velocity"),
    ("current_a", "current_a", "f", "A", "the motor current"),
    ("motor_torque_nm", "motor_torque_nm", "f", "N·m", "the motor's torque"),
    ("friction_torque_nm", "friction_torque_nm", "f", "N·m", "the friction torque"),
    ("encoder_x4", "encoder_x4", "i", "counts", "the encoder's true x4 count"),
    ("stuck", "stuck", "b", "", "friction holds the joint"),
    ("at_stop", "at_stop", "b", "", "the link is against a hard stop"),
    ("amp_enabled", "amp_enabled", "b", "", "the amplifier drives (enabled, not faulted)"),
    ("brake_engaged", "brake_engaged", "b", "", "the holding brake holds"),
)
#: a quadrature net's per-period summary (group ``net.<net>``): what the decoder's sampler saw
QUADRATURE: tuple[tuple[str, str, str, str], ...] = (
    ("counts", "i", "counts", "net x4 counts in the period"),
    ("illegal", "i", "", "samples with A and B both changed"),
    ("index", "i", "", "index pulses in the period"),
    ("phase", "i", "", "the quadrature state at the period's end (0..3)"),
)
#: one bus cycle (group ``bus``; events, not per tick)
BUS: tuple[tuple[str, str, str, str], ...] = (
    ("space", "i", "bits", "the address space: 16, 24 or 32 (A16, A24, A32)"),
    ("address", "i", "", "the address"),
    ("width", "i", "bits", "the data width: 8, 16 or 32"),
    ("write", "b", "", "a write (else a read)"),
    ("value", "i", "", "the value read or written (0 for a cycle that ended in BERR)"),
    ("block", "b", "", "a block (BLT) cycle"),
    ("berr", "b", "", "the cycle ended in BERR"),
    ("cycle", "i", "", "the cycle's number in the trace (each cycle shows in a VCD)"),
)
IRQ_LEVELS = range(1, 8)


class Catalog:
    """The signals of one rig, in a fixed order (joints, drivers, nets, truth, IRQs, bus)."""

    def __init__(self, signals: Iterable[Signal]) -> None:
        self.signals = tuple(signals)
        self.by_name = {s.name: s for s in self.signals}
        self.groups = tuple(dict.fromkeys(s.group for s in self.signals))

    def __len__(self) -> int:
        return len(self.signals)

    def select(self, spec: str, *, flag: str = "--trace") -> tuple[Signal, ...]:
        """The signals ``spec`` chooses, in catalog order (grammar: the module docstring)."""
        items = [i.strip() for i in spec.split(",")]
        if not any(items):
            raise TraceSpecError(f"{flag} {spec!r}: an empty SPEC; give names or patterns ({flag} list prints them)")
        chosen: dict[str, None] = {}
        for item in items:
            if not item:
                continue
            drop = item.startswith("-")
            pattern = item[1:] if drop else item
            names = self._match(pattern)
            if not names:
                raise TraceSpecError(f"{flag} {spec!r}: {pattern!r} matches no signal; nearest: "
                                     f"{', '.join(self.nearest(pattern)) or '-'} ({flag} list prints them all)")
            for n in names:
                if drop:
                    chosen.pop(n, None)
                else:
                    chosen[n] = None
        if not chosen:
            raise TraceSpecError(f"{flag} {spec!r}: the items remove every signal they chose")
        return tuple(s for s in self.signals if s.name in chosen)

    def _match(self, pattern: str) -> list[str]:
        if pattern in self.groups:
            pattern += ".*"
        if not any(c in pattern for c in "*?["):
            return [pattern] if pattern in self.by_name else []
        return [s.name for s in self.signals if fnmatch.fnmatchcase(s.name, pattern)]

    def nearest(self, pattern: str, n: int = 4) -> list[str]:
        """The names and group patterns closest to ``pattern`` (difflib's ratio)."""
        candidates = [*self.by_name, *(g + ".*" for g in self.groups)]
        return difflib.get_close_matches(pattern, candidates, n=n, cutoff=0.3)

    def listing(self) -> str:
        """Every name with its unit and meaning, one a line (``--trace list``)."""
        width = max((len(s.name) for s in self.signals), default=0)
        return "\n".join(f"{s.name:<{width}}  {s.unit or '-':<7} {s.doc}" for s in self.signals)


def build_catalog(joints: Sequence[str], *, analog_nets: Iterable[str] = (), digital_nets: Iterable[str] = (),
                  quadrature_nets: Iterable[str] = (), truth: bool = False, irq: bool = False,
                  bus: bool = False, controller: bool = True) -> Catalog:
    """The catalog of a rig with ``joints``: the controller's and the drivers' signals always; the
    nets, the plant's truth, the IRQ lines and the bus cycles where the rig has them (an emulated
    crate has all; a real bus has none of them). ``controller=False``: no controller or drivers
    (the coordinator of unit controllers serves the plant and runs no loop)."""
    out: list[Signal] = []
    for j in joints if controller else ():
        out += [Signal(f"{j}.{leaf}", kind, unit, doc) for leaf, kind, unit, doc in CONTROLLER]
    for j in joints if controller else ():
        out += [Signal(f"drv.{j}.{leaf}", kind, unit, doc) for leaf, kind, unit, doc in DRIVER]
    nets = [(n, "f", "V", "analog net (volts)") for n in analog_nets]
    nets += [(n, "b", "", "digital net (logic level)") for n in digital_nets]
    for name, kind, unit, doc in sorted(nets):
        out.append(Signal(f"net.{name}", kind, unit, doc))
    for name in sorted(quadrature_nets):
        out += [Signal(f"net.{name}.{leaf}", kind, unit, doc) for leaf, kind, unit, doc in QUADRATURE]
    if truth:
        for j in joints:
            out += [Signal(f"truth.{j}.{leaf}", kind, unit, doc) for leaf, _key, kind, unit, doc in TRUTH]
    if irq:
        out += [Signal(f"irq.IRQ{level}", "i", "", f"interrupts acknowledged at level {level} in the tick")
                for level in IRQ_LEVELS]
    if bus:
        out += [Signal(f"bus.{leaf}", kind, unit, doc, per_tick=False) for leaf, kind, unit, doc in BUS]
    return Catalog(out)
