"""``vmehil calibrate encoder``: counts per revolution index to index, index position, direction.

Method, for every joint with an encoder wired (a motor-shaft encoder with one index per motor
revolution) — all of them in one tour, as the pot procedure does (the joints are independent
mechanisms, each on its own decoder channel; one tour instead of one per joint):

1. Open a decoder driver on each joint's channel and arm the index latch.
2. With the servo loop, move the joints slowly forward by ``revs`` motor revolutions
   (``revs · 2π / N`` of joint angle; one coordinated move, no motor faster than ``speed``
   rev/s), then back to where they started. After every servo tick, for each joint,
   if the index was captured, take its count (:meth:`QuadratureDriver.home_at_index`, which
   re-arms the latch) and the joint angle at that instant (fixture in ``--auto``, else the
   loop's own position reading).
3. Counts per motor revolution = the difference between successive index captures in the
   forward pass (all must agree within ``consistency_counts``: a missed or extra count shows
   here); the joint-side figure is that times the gear ratio from the rig.
4. Direction: the index counts must increase while the joint angle increases (A leads B for a
   positive move); otherwise the check fails and says to swap A and B.
5. Index position: the joint angle of the first forward index (for homing), and the backlash
   of the index between the forward and the backward pass (counts).

Nominal values (``[joint.encoder] lines_per_rev``, ``[joint.gear] ratio``) come from the rig file.
"""

from __future__ import annotations

import math

import numpy as np

from hal.quadrature.quad import QuadratureDriver
from vmehil.calibration.base import CalibrationAbort, CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import CalibrationStore, JointCal, rig_boards, utc_now


def encoder_nominal(joint) -> tuple[float, float]:
    """(x4 counts per motor revolution, gear ratio) from the rig file's joint tables."""
    enc = joint.table.table("encoder", {})
    gear = joint.table.table("gear", {})
    return 4.0 * enc.get_float("lines_per_rev", 500.0, min=1.0), gear.get_float("ratio", 1.0, min=1e-6)


def _group_indices(counts: np.ndarray, tolerance: float) -> list[list[int]]:
    """Capture numbers grouped by index (sorted by count; a new group past ``tolerance`` counts)."""
    groups: list[list[int]] = []
    last = None
    for i in np.argsort(counts, kind="stable"):
        if last is None or counts[i] - last > tolerance:
            groups.append([])
        groups[-1].append(int(i))
        last = counts[i]
    for g in groups:
        g.sort()
    return groups


class EncoderProcedure:
    name = "encoder"
    version = 1
    title = "encoders: counts/rev index to index, index position, direction"

    consistency_counts = 1.0  #: index-to-index intervals must agree to this many counts
    cpr_limit_counts = 1.0  #: measured counts/rev vs nominal (lines·4)

    def __init__(self, revs: float = 3.5, speed_motor_rev_s: float = 1.0) -> None:
        self.revs = revs
        self.speed = speed_motor_rev_s

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        joints = [j for j in (ctx.rig.joints[i] for i in ctx.selected_joints()) if "encoder" in j.wiring]
        if not joints:
            res.skipped.append("no joint with an encoder wired")
            return res
        pos = ctx.positioner()
        res.data["joints"] = {}
        # Every joint at once (as the pot tour): one decoder channel each, all moved forward
        # together by ``revs`` motor revolutions and back, no faster than ``speed`` motor rev/s
        # each; the joints are independent mechanisms, so a joint's captures are those it would
        # give alone — in one tour instead of one per joint.
        setup = []
        for j in joints:
            pin = j.wiring["encoder"]
            ident = rig_boards(ctx.rig)[pin.board]
            nominal, ratio = encoder_nominal(j)
            drv = QuadratureDriver(ctx.bus, ident.base, space=ident.space, counts_per_rev=nominal,
                                   channels=[pin.index], errors="report")
            drv.arm_index(pin.index)
            start = pos.position(j.index)
            span = self.revs * 2 * math.pi / ratio
            setup.append((j, pin.index, drv, nominal, ratio, start, span))
            ctx.say(f"  {j.name}: moving {math.degrees(span):+.2f}° and back "
                    f"({self.revs:g} motor revolutions each way)")
        captured: dict[int, list[tuple[int, float, int]]] = {j.index: [] for j in joints}  # (count, angle, dir)
        direction = [1]

        def on_tick() -> None:
            for j, ch, drv, *_ in setup:
                if drv.index_seen(ch):
                    idx = drv.home_at_index(ch)
                    angle = ctx.fixture.joint_angle(j.index) if ctx.auto and ctx.fixture else pos.position(j.index)
                    captured[j.index].append((idx, float(angle), direction[0]))

        speeds = {j.index: self.speed * 2 * math.pi / ratio for j, _c, _d, _n, ratio, _s, _sp in setup}
        ctx.progress("encoder", 0, 2)
        pos.move_to({j.index: start + span for j, _c, _d, _n, _r, start, span in setup}, settle_s=0.3,
                    on_tick=on_tick, speed_rad_s=speeds)
        direction[0] = -1
        ctx.progress("encoder", 1, 2)
        pos.move_to({j.index: start for j, _c, _d, _n, _r, start, _sp in setup}, settle_s=0.3, on_tick=on_tick,
                    speed_rad_s=speeds)
        fault = pos.faulted()
        if fault:
            raise CalibrationAbort(f"the servo loop stopped while moving the encoders' joints: {fault}")
        for j, _ch, _drv, nominal, ratio, _start, _span in setup:
            captures = captured[j.index]
            # A joint at rest may dither across an index (limit cycle, noise): the same index is
            # then captured again and again, from either side (±1 count). Group the captures
            # by index (within a quarter of the nominal revolution) and use one count per index.
            counts_all = np.array([c[0] for c in captures], dtype=float)
            angles_all = np.array([c[1] for c in captures])
            groups = _group_indices(counts_all, nominal / 4)
            if len(groups) < 2:
                raise CalibrationAbort(f"{j.name}: saw {len(groups)} distinct index pulse(s), need 2: check the index "
                                       "wiring and the gear ratio in the rig file")
            firsts = [g[0] for g in groups]  # first capture of each index
            counts = counts_all[firsts]
            angles = angles_all[firsts]
            diffs = np.diff(counts)
            cpr = float(np.median(diffs))
            spread = float(np.max(np.abs(diffs - cpr)))
            sign = 1 if np.polyfit(angles_all, counts_all, 1)[0] > 0 else -1
            order = np.argsort(angles)
            counts, angles = counts[order], angles[order]
            # hysteresis: the same index captured moving back vs moving forward
            hyst = [counts_all[i] - counts_all[g[0]] for g in groups for i in g if captures[i][2] < 0]
            backlash = float(np.median(hyst)) if hyst else None
            ctx.say(f"  {j.name}: {cpr:.0f} counts/motor rev over {len(diffs)} revolutions (spread {spread:.0f}), "
                    f"direction {'+' if sign > 0 else '−'}, first index at {math.degrees(angles[0]):+.3f}°")
            res.checks += [
                Check(f"{j.name} counts/rev − nominal {nominal:.0f}", cpr - nominal, "counts", self.cpr_limit_counts),
                Check(f"{j.name} index-to-index spread", spread, "counts", self.consistency_counts),
                Check(f"{j.name} direction (counts rise with angle)", float(sign > 0), "", 0.0, kind="bool",
                      note="" if sign > 0 else "swap the A and B wires (or the motor leads and the tach)"),
            ]
            values = {"counts_per_motor_rev": cpr, "counts_per_joint_rev": cpr * ratio, "ratio": ratio,
                      "direction": sign, "index_joint_angle_rad": float(angles[0]),
                      "index_spacing_rad": 2 * math.pi / ratio}
            if backlash is not None:
                values["index_hysteresis_counts"] = backlash
            update.set_joint(j.name, JointCal(self.name, self.version, utc_now(), values))
            res.data["joints"][j.name] = {**values, "captures": [list(c) for c in captures], "spread_counts": spread}
        ctx.progress("encoder", 2, 2)
        return res
