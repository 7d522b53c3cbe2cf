"""``vmehil calibrate pot``: the JPL paper's potentiometer calibration — nine readings 45° apart
over the joint's travel, joined by eight line segments.

Method (all selected joints at once, so the arm makes one tour):

1. Targets per joint: ``points`` (9) angles centred in the joint's travel, ``spacing_deg`` (45°)
   apart — or closer, evenly, when the travel is shorter than 8 × 45° (a joint that turns
   less than 360° still gets nine points spread over what it can reach). The travel is
   ``[joint.calibration] pot_travel_deg = [lo, hi]`` or the link's stops less 3°.
   Between two calibration points, ``verify_per_segment`` verification stops are added.
2. Stops are visited in ascending order (the pot is always approached from the same side).
   At each stop the servo loop (on its configured position sensor) moves the joints there
   and holds them; the exact stop does not matter because the reference angle is measured
   there: with ``--auto`` the fixture (emulator: the joint's true angle), averaged over the
   same ``average_s`` window as the pot volts; otherwise the operator reads the angle with a
   level/protractor and types it (the paper: "a level can be used to verify the 45 deg.
   settings").
3. The pot volts (ADC, calibration in force) averaged over ``average_s`` and the reference
   angle at the nine calibration stops form the table (:class:`servo.io.PotCalibration`).
4. Residuals at the verification stops — points the table was *not* fitted to — before
   (nominal straight line of the pot's datasheet) and after (the table), in arcmin.

The accuracy scale is the paper's: 3 arcmin at joint 1 ≈ 1 mm at full boom extension.
"""

from __future__ import annotations

import math

import numpy as np

from servo.io import PotCalibration
from servo.settings import soft_limits_rad
from vmehil.calibration.base import CalibrationAbort, CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import CalibrationStore, JointCal, utc_now

ARCMIN_PER_RAD = 180.0 * 60.0 / math.pi


#: how far inside a soft limit the pot calibration stays (the presets' soft limits are 2° inside the
#: hard stops, so this is the stops less 3°, as before soft limits existed)
SOFT_LIMIT_CLEARANCE_DEG = 1.0


def pot_travel(joint, margin_deg: float = 3.0,
               soft_rad: tuple[float, float] = (-math.inf, math.inf)) -> tuple[float, float]:
    """Travel (rad) to calibrate over: ``[joint.calibration] pot_travel_deg`` when the rig states
    it, else the joint's hard stops (``[joint.link]``) less ``margin_deg`` and never closer than
    :data:`SOFT_LIMIT_CLEARANCE_DEG` to its soft limits ``soft_rad`` — a joint whose stops its
    plant template states (melmalec's legs) has no ``[joint.link]`` of its own, and without the soft
    limits its travel was ±177°, past the stops."""
    cal = joint.table.table("calibration", {})
    if "pot_travel_deg" in cal:
        lo, hi = cal.floats("pot_travel_deg", length=2)
        return math.radians(lo), math.radians(hi)
    link = joint.table.table("link", {})
    m = math.radians(margin_deg)
    c = math.radians(SOFT_LIMIT_CLEARANCE_DEG)
    lo = max(link.get_float("lower_stop_rad", -math.pi) + m, soft_rad[0] + c)
    hi = min(link.get_float("upper_stop_rad", math.pi) - m, soft_rad[1] - c)
    return lo, hi


def pot_targets(lo: float, hi: float, points: int = 9, spacing_rad: float = math.radians(45.0)) -> np.ndarray:
    """``points`` angles centred in [lo, hi], ``spacing_rad`` apart or evenly spread if that does not fit."""
    if hi <= lo:
        raise ValueError(f"pot travel [{lo}, {hi}] rad is empty")
    step = min(spacing_rad, (hi - lo) / (points - 1))
    centre = 0.5 * (lo + hi)
    return centre + (np.arange(points) - (points - 1) / 2) * step


class PotProcedure:
    name = "pot"
    version = 1
    title = "potentiometers: nine points 45° apart, eight linear segments"

    #: Tolerances (arcmin) on the residual at verification points: the paper's accuracy scale
    #: (3 arcmin ≈ 1 mm at full reach) for the rms. The jpl-arm pots (bow ≈ 1°, winding ripple
    #: ≈ 2 arcmin) reach 0.4–1.4 arcmin rms; a ripple eight segments cannot follow fails here
    #: (use more points). 12-bit conversion is 5 arcmin per LSB. See docs/calibration.md.
    residual_rms_limit_arcmin = 3.0
    residual_max_limit_arcmin = 5.0

    def __init__(self, points: int = 9, spacing_deg: float = 45.0, verify_per_segment: int = 1,
                 settle_s: float = 1.0, average_s: float = 1.0) -> None:
        if points < 2:
            raise ValueError("a pot table needs at least two points")
        self.points = points
        self.spacing = math.radians(spacing_deg)
        self.verify = verify_per_segment
        self.settle_s = settle_s
        self.average_s = average_s

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        joints = [j for j in (ctx.rig.joints[i] for i in ctx.selected_joints()) if "pot" in j.wiring]
        if not joints:
            res.skipped.append("no joint with a potentiometer wired")
            return res
        pos = ctx.positioner()
        # Per joint: calibration targets and the stops (targets + verification points between).
        plan: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        soft_min, soft_max = soft_limits_rad(ctx.rig)
        for j in joints:
            soft = (soft_min[j.index], soft_max[j.index])
            targets = pot_targets(*pot_travel(j, soft_rad=soft), self.points, self.spacing)
            fr = np.arange(self.verify + 1) / (self.verify + 1)
            stops = np.concatenate([targets[k] + fr * (targets[k + 1] - targets[k]) for k in range(len(targets) - 1)]
                                   + [targets[-1:]])
            is_cal = np.zeros(len(stops), bool)
            is_cal[:: self.verify + 1] = True
            plan[j.index] = (targets, stops, is_cal)
            ctx.say(f"  {j.name}: {self.points} points from {math.degrees(targets[0]):+.1f}° to "
                    f"{math.degrees(targets[-1]):+.1f}°, {math.degrees(targets[1] - targets[0]):.2f}° apart; "
                    f"{self.verify} verification point(s) per segment")
        n_stops = len(next(iter(plan.values()))[1])
        volts = {j.index: np.zeros(n_stops) for j in joints}
        ref = {j.index: np.zeros(n_stops) for j in joints}
        ticks = max(1, round(self.average_s / pos.period_s))
        for s in range(n_stops):
            ctx.progress("pot stops", s, n_stops)
            pos.move_to({j.index: float(plan[j.index][1][s]) for j in joints}, settle_s=self.settle_s)
            fault = pos.faulted()
            if fault:
                raise CalibrationAbort(f"the servo loop stopped on the way to stop {s + 1}: {fault}")
            acc_v: dict[int, list[float]] = {j.index: [] for j in joints}
            acc_a: dict[int, list[float]] = {j.index: [] for j in joints}

            def sample(acc_v=acc_v, acc_a=acc_a) -> None:
                for j in joints:
                    pin = j.wiring["pot"]
                    acc_v[j.index].append(pos.io.adc[pin.board].read_volts(pin.index))
                    if ctx.auto and ctx.fixture is not None:
                        acc_a[j.index].append(ctx.fixture.joint_angle(j.index))

            pos.hold(ticks * pos.period_s, on_tick=sample)
            for j in joints:
                volts[j.index][s] = float(np.mean(acc_v[j.index]))
                nominal = float(plan[j.index][1][s])
                ref[j.index][s] = (float(np.mean(acc_a[j.index])) if acc_a[j.index]
                                   else ctx.reference_angle(j.index, nominal))
        ctx.progress("pot stops", n_stops, n_stops)
        res.data["joints"] = {}
        for j in joints:
            _targets, _stops, is_cal = plan[j.index]
            v, a = volts[j.index], ref[j.index]
            if np.any(np.diff(v[is_cal]) == 0):
                raise CalibrationAbort(f"{j.name}: two calibration points read the same pot volts; is the wiper "
                                       "connected and the joint moving?")
            table = PotCalibration(list(v[is_cal]), list(a[is_cal]))
            sc = pos.io.scaling[j.index]
            verify = ~is_cal if (~is_cal).any() else is_cal
            after = np.array([table.angle(x) for x in v[verify]]) - a[verify]
            before = (v[verify] - sc.pot_zero_v) / sc.pot_v_per_rad - a[verify]
            figures = {
                "before_rms_arcmin": _rms(before) * ARCMIN_PER_RAD,
                "before_max_arcmin": float(np.max(np.abs(before))) * ARCMIN_PER_RAD,
                "residual_rms_arcmin": _rms(after) * ARCMIN_PER_RAD,
                "residual_max_arcmin": float(np.max(np.abs(after))) * ARCMIN_PER_RAD,
            }
            ctx.say(f"  {j.name}: residual {figures['before_rms_arcmin']:.1f} → {figures['residual_rms_arcmin']:.2f} "
                    f"arcmin rms (max {figures['before_max_arcmin']:.1f} → {figures['residual_max_arcmin']:.2f}) "
                    f"at {int(verify.sum())} verification points")
            res.checks += [
                Check(f"{j.name} residual rms", figures["residual_rms_arcmin"], "arcmin",
                      self.residual_rms_limit_arcmin),
                Check(f"{j.name} residual max", figures["residual_max_arcmin"], "arcmin",
                      self.residual_max_limit_arcmin),
                Check(f"{j.name} improvement (before/after rms)",
                      figures["before_rms_arcmin"] / max(figures["residual_rms_arcmin"], 1e-9), "×", 1.0, kind="min"),
            ]
            values = {"volts": [float(x) for x in table.volts], "angles_rad": [float(x) for x in table.angles],
                      **figures, "verification_points": int(verify.sum())}
            update.set_joint(j.name, JointCal(self.name, self.version, utc_now(), values))
            res.data["joints"][j.name] = {
                "points": [{"volts": float(x), "angle_deg": math.degrees(y)} for x, y in zip(v[is_cal], a[is_cal],
                                                                                               strict=True)],
                "verification": [{"volts": float(x), "angle_deg": math.degrees(y),
                                  "residual_arcmin": r * ARCMIN_PER_RAD, "before_arcmin": b * ARCMIN_PER_RAD}
                                 for x, y, r, b in zip(v[verify], a[verify], after, before, strict=True)],
                **figures,
            }
        # Top-level summary (the JSON contract): the points per joint and the worst joint's figures.
        per = res.data["joints"]
        res.data["points"] = {name: d["points"] for name, d in per.items()}
        for key in ("before_rms_arcmin", "before_max_arcmin", "residual_rms_arcmin", "residual_max_arcmin"):
            res.data[key] = max(d[key] for d in per.values())
        return res


def _rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))
