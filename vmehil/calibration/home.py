"""``vmehil calibrate home`` (console ``home J``): home each positioned joint's encoder to the motor
index the calibrated pot chooses.

The positioned joints close their loop on the pot; the motor's encoder gives an index pulse once
per motor turn, every ``2π/N`` of joint travel (3.6° at N = 100). The pot cannot tell one index
from the next to a count, but it tells *which* one: the index nearest the pot's calibrated
position (within half a spacing). Homing (as LinuxCNC's ``HOME_USE_INDEX``, with the pot as the
home switch), for every selected joint at once:

1. The joint's index grid: ``θ_k = φ + k·s`` with the spacing ``s = 2π/N`` and the phase ``φ`` —
   the joint angle at which the index fires — from the encoder calibration (``index_spacing_rad``,
   ``index_joint_angle_rad``) when there is one, else the nominal ratio (``[joint.servo.nominal]
   ratio``) and ``[joint.calibration] index_deg`` (default 0: the index at joint zero, modulo
   one motor turn — the presets' encoders are mounted so).
2. The pot chooses the index: ``k = round((θ_pot − φ)/s)``.
3. Move (at the rig's speed) to ``θ_k − s/2``, arm the decoder's index latch, and pass slowly
   upwards to ``θ_k + s/2`` (``speed`` motor revolutions per second): the only index in that span
   is ``θ_k``, always approached from below, so the same index and the same edge are found
   wherever the joint started.
4. At the capture the loop's own decoder is homed there (:meth:`servo.io.JointIO.home_encoder`):
   the index count reads ``θ_k``, so the encoder gives the joint's absolute angle from then on
   (``status``: ``homed=yes``, ``enc_deg``; the watchdog's encoder/pot cross-check compares the
   two absolutely). The loop's position source stays the pot.
5. The joint returns to ``θ_k`` and holds.

Checks: the index was captured; the pot agrees with the chosen index at the capture within a
quarter spacing (beyond, the pot or the index grid is wrong and the choice is not safe).

Recorded per joint in the calibration file (``[joint.NAME.home]``): ``index_angle_rad``,
``index_counts`` (the decoder's unwrapped count at the index, this session), ``offset_counts``
(the count at joint angle 0), ``counts_per_joint_rev``, ``index_spacing_rad``,
``index_phase_rad``, ``phase_from`` and ``pot_minus_index_rad``. The record is never put in force
when a session starts: an incremental encoder loses its count at power-off, so each session homes
again.

Exempt (skipped): joints without a pot or an encoder, or whose loop closes on the encoder — a
continuous joint such as melmalec's crawler.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from servo.nominal import rig_nominal
from vmehil.calibration.base import CalibrationAbort, CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import CalibrationStore, JointCal, utc_now


@dataclass(frozen=True)
class IndexGrid:
    """Where a joint's motor index fires: at ``phase_rad + k·spacing_rad`` (joint angle, rad)."""

    spacing_rad: float
    phase_rad: float
    source: str  #: where the phase came from: ``encoder calibration`` or ``nominal``

    def nearest(self, angle_rad: float) -> float:
        """The index angle nearest ``angle_rad`` (the pot's choice)."""
        k = round((angle_rad - self.phase_rad) / self.spacing_rad)
        return self.phase_rad + k * self.spacing_rad


def index_grid(ctx: CalibrationContext, joint: int) -> IndexGrid:
    """Joint ``joint``'s index grid: the encoder calibration's when there is one, else nominal."""
    j = ctx.rig.joints[joint]
    enc = ctx.store.joint_entry(j.name, "encoder")
    if enc is not None and "index_spacing_rad" in enc.values and "index_joint_angle_rad" in enc.values:
        return IndexGrid(float(enc.values["index_spacing_rad"]), float(enc.values["index_joint_angle_rad"]),
                         "encoder calibration")
    ratio = rig_nominal(ctx.rig)[joint].ratio
    cal = j.table.table("calibration", {})
    phase = math.radians(cal.get_float("index_deg", 0.0))
    return IndexGrid(2.0 * math.pi / ratio, phase, "nominal")


def exempt_reason(ctx: CalibrationContext, joint: int, homeable: bool) -> str | None:
    """Why joint ``joint`` is not homed (``None``: it is homeable)."""
    if homeable:
        return None
    j = ctx.rig.joints[joint]
    if "pot" not in j.wiring:
        return f"{j.name}: exempt (no pot: a continuous joint, its loop closes on the encoder)"
    if "encoder" not in j.wiring:
        return f"{j.name}: exempt (no encoder to home)"
    return f"{j.name}: exempt (its loop closes on the encoder)"


class HomeProcedure:
    name = "home"
    version = 1
    title = "home the encoders to the motor index the calibrated pot chooses"

    def __init__(self, speed_motor_rev_s: float = 0.5, settle_s: float = 0.2) -> None:
        self.speed = speed_motor_rev_s
        self.settle_s = settle_s

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        pos = ctx.positioner()
        io = pos.io
        todo: list[int] = []
        for i in ctx.selected_joints():
            why = exempt_reason(ctx, i, bool(io.homeable[i]))
            if why is not None:
                res.skipped.append(why)
                continue
            name = ctx.rig.joints[i].name
            if ctx.store.joint_entry(name, "pot") is None:
                raise CalibrationAbort(f"{name}: its pot is not calibrated, and homing chooses the index by the pot's "
                                       "calibrated position; run `vmehil calibrate pot --auto` first")
            todo.append(i)
        if not todo:
            res.skipped.append("no joint to home")
            return res
        res.data["joints"] = {}
        grids = {i: index_grid(ctx, i) for i in todo}
        chosen = {i: grids[i].nearest(pos.position(i)) for i in todo}
        for i in todo:
            g = grids[i]
            ctx.say(f"  {ctx.rig.joints[i].name}: pot at {math.degrees(pos.position(i)):+.3f}°, index every "
                    f"{math.degrees(g.spacing_rad):.3f}° ({g.source}): homing to the index at "
                    f"{math.degrees(chosen[i]):+.3f}°, approached from below")
        ctx.progress("home", 0, 3)
        # 1. below the chosen index by half a spacing (no other index is nearer), at the rig's speed
        pos.move_to({i: chosen[i] - grids[i].spacing_rad / 2 for i in todo}, settle_s=self.settle_s)
        self._check_running(pos)
        ctx.progress("home", 1, 3)
        # 2. arm the latch and pass slowly up through the index
        channels = {i: io.encoder_channel(i) for i in todo}
        for drv, ch in channels.values():
            drv.arm_index(ch)
        captured: dict[int, tuple[int, float]] = {}  # joint -> (index count, pot angle at the capture)

        def on_tick() -> None:
            for i, (drv, ch) in channels.items():
                if i not in captured and drv.index_seen(ch):
                    pot = pos.position(i)
                    captured[i] = (io.home_encoder(i, chosen[i]), pot)

        speeds = {i: self.speed * grids[i].spacing_rad for i in todo}
        try:
            pos.move_to({i: chosen[i] + grids[i].spacing_rad / 2 for i in todo}, settle_s=self.settle_s,
                        on_tick=on_tick, speed_rad_s=speeds)
            self._check_running(pos)
            ctx.progress("home", 2, 3)
            # 3. back to the home: the index
            pos.move_to({i: chosen[i] for i in todo}, settle_s=self.settle_s)
            self._check_running(pos)
        except BaseException:
            for i in captured:  # a homing cut short homes nothing
                io.clear_home(i)
            raise
        ctx.progress("home", 3, 3)
        for i in todo:
            j = ctx.rig.joints[i]
            g = grids[i]
            got = captured.get(i)
            res.checks.append(Check(f"{j.name} index captured", float(got is not None), "", 0.0, kind="bool",
                                    note="" if got is not None else "no index in the pass: check the index wiring"))
            if got is None:
                io.clear_home(i)
                continue
            idx, pot = got
            drv, ch = channels[i]
            cpr = drv.counts_per_rev(ch)
            off = pot - chosen[i]
            res.checks.append(Check(f"{j.name} pot - index angle at the capture", math.degrees(off), "deg",
                                    math.degrees(g.spacing_rad / 4),
                                    note="" if abs(off) <= g.spacing_rad / 4 else
                                    "the pot and the index grid disagree: calibrate the pot (and the encoder)"))
            if abs(off) > g.spacing_rad / 4:
                io.clear_home(i)  # the choice of index is not safe: not homed
            values = {"index_angle_rad": chosen[i], "index_counts": int(idx),
                      "offset_counts": float(idx - chosen[i] * cpr / (2.0 * math.pi)),
                      "counts_per_joint_rev": float(cpr), "index_spacing_rad": g.spacing_rad,
                      "index_phase_rad": g.phase_rad, "phase_from": g.source, "pot_minus_index_rad": off,
                      "approach": "up"}
            ctx.say(f"  {j.name}: index at {math.degrees(chosen[i]):+.4f}° captured at count {idx} "
                    f"(offset {values['offset_counts']:+.1f} counts at 0°; the pot read {math.degrees(off):+.4f}° "
                    "from it): homed")
            update.set_joint(j.name, JointCal(self.name, self.version, utc_now(), values))
            res.data["joints"][j.name] = values
        return res

    @staticmethod
    def _check_running(pos) -> None:
        fault = pos.faulted()
        if fault:
            raise CalibrationAbort(f"the servo loop stopped while homing: {fault}")
