"""Holding brakes: spring-applied, power-released brakes on the motor shafts, vectorised.

Per joint (``[joint.holding_brake]``, :class:`emulators.plant.params.HoldingBrakeParams`): the
brake's line energised releases it, low engages it. The armature follows the line after a delay
(``engage_delay_s`` after it drops, ``release_delay_s`` after it rises); a line that returns to
the armature's state before the armature moved cancels the pending move. Engaged, the brake adds
``holding_torque_nm / N`` to the motor shaft's static and kinetic friction (it holds up to the
holding torque at the joint and slips beyond it with kinetic friction at the holding torque:
:class:`emulators.plant.friction.StickSlipStepper`); released it adds nothing.

The line the brake sees is the command's line *and* the amplifiers' enable watchdog's: the
charge pump also feeds the brakes' supply, so a pump that runs out drops every brake line, and
an amplifier it latched off keeps its brake engaged until the amplifier is re-armed
(:class:`emulators.plant.amplifier.EnableWatchdog`).

Within one servo period the plant sees line events at substeps (the new command at the
computation delay, the pump running out); :class:`HoldingBrakes` turns them into the substeps at
which each armature moves (``flips``), the same for the numpy path and the compiled kernel.
"""

from __future__ import annotations

import math

import numpy as np

MAX_FLIPS = 3  #: armature moves per joint in one period: one pending from before, one per line event


class HoldingBrakes:
    """The brakes' state (per joint) and the armature moves of the period being integrated.

    ``present``: the joints that have a brake; ``hold_motor_nm``: what each holds at the motor
    shaft (holding torque / N; 0 where none); ``engage_s``/``release_s``: the delays.
    """

    def __init__(self, present: np.ndarray, hold_motor_nm: np.ndarray, engage_s: np.ndarray,
                 release_s: np.ndarray) -> None:
        self.present = np.asarray(present, dtype=bool)
        self.hold_motor_nm = np.where(self.present, np.asarray(hold_motor_nm, dtype=float), 0.0)
        self.engage_s = np.asarray(engage_s, dtype=float)
        self.release_s = np.asarray(release_s, dtype=float)
        self.any = bool(self.present.any())
        n = self.present.size
        self.flips = np.full((MAX_FLIPS, n), -1, dtype=np.int64)
        self.reset()

    def reset(self) -> None:
        """At rest with no power: every brake engaged, its line low, nothing pending."""
        n = self.present.size
        self.engaged = self.present.copy()  #: the armature holds (mechanical state)
        self.line = np.zeros(n, dtype=bool)  #: the line level the brake last saw (True: energised)
        self.switch_s = np.full(n, math.inf)  #: plant time the pending armature move completes
        self._n_flips = np.zeros(n, dtype=np.int64)

    # ---- one period -------------------------------------------------------------------------
    def begin(self, t0_s: float, h: float) -> np.ndarray:
        """Start a period at plant time ``t0_s`` with substep ``h``; returns the engaged state at
        its start (a copy: the compiled kernel's starting point)."""
        self._t0 = t0_s
        self._h = h
        self.flips[:] = -1
        self._n_flips[:] = 0
        self._at_start = self.engaged.copy()
        return self._at_start

    def _mature(self, upto: int) -> None:
        """Armature moves completing before substep ``upto`` happen (recorded in ``flips``)."""
        pending = np.isfinite(self.switch_s)
        if not pending.any():
            return
        s = np.ceil((self.switch_s - self._t0) / self._h - 1e-9)
        due = pending & (s < upto)
        if not due.any():
            return
        for j in np.flatnonzero(due):
            self.flips[self._n_flips[j], j] = max(0, int(s[j]))
            self._n_flips[j] += 1
        self.engaged = self.engaged ^ due
        self.switch_s = np.where(due, math.inf, self.switch_s)

    def event(self, s: int, line: np.ndarray) -> None:
        """The brakes' lines are ``line`` (True: energised) from substep ``s`` of the period on."""
        self._mature(s)
        line = np.asarray(line, dtype=bool) & self.present
        changed = line != self.line
        if not changed.any():
            return
        self.line = line
        want_engaged = ~line
        cancel = changed & (want_engaged == self.engaged)
        start = changed & ~cancel
        t = self._t0 + s * self._h
        self.switch_s = np.where(cancel, math.inf, self.switch_s)
        self.switch_s = np.where(start, t + np.where(want_engaged, self.engage_s, self.release_s), self.switch_s)

    def torque_at(self, s: int) -> np.ndarray:
        """Motor-shaft holding torque per joint during substep ``s`` (0 where released)."""
        self._mature(s + 1)
        return np.where(self.engaged, self.hold_motor_nm, 0.0)

    def finish(self, n_sub: int) -> None:
        """End of the period: moves completing inside it happen."""
        self._mature(n_sub)

    # ---- outside simulated time -------------------------------------------------------------
    def hold(self) -> np.ndarray:
        """Engage every brake now (the plant node's command timeout: wall-clock time has passed,
        longer than any engage delay, while simulated time stood still); returns the brakes this
        engaged."""
        new = self.present & ~self.engaged
        self.engaged = self.present.copy()
        self.line = np.zeros_like(self.line)
        self.switch_s = np.full_like(self.switch_s, math.inf)
        return new
