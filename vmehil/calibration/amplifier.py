"""``vmehil calibrate amplifier``: transconductance gain and offset from the current monitor,
and the current-limit check, for every linear (transconductance) amplifier.

The arm must stay where it is while currents are applied (gravity joints would fall with the
servo off), so the servo loop keeps holding every joint and the procedure borrows one joint's
amplifier command for one servo period at a time (:meth:`Positioner.override_command`):

Every joint is pulsed at once (independent mechanisms, each on its own DAC channel and monitor
input: one series of pulses for the arm, not one per joint).

1. For each test level ``v`` (fractions of full command), command ``+v`` for one period, read
   the current monitor at the next sampling instant, then ``−v`` for one period (which undoes
   the small motion of the first pulse), read again; give the joint back to the loop to
   settle. One period is many amplifier time constants, so the monitor reads the settled
   current ``i = gain·v + offset``.
2. Fit ``i`` against ``v`` (least squares): ``gain_a_per_v`` and ``offset_a``. The command
   path is measured end to end — DAC channel errors included — which is what the servo uses.
   The monitor scaling (V/A, from the rig) is the reference: it is a precision shunt.
3. Current limit: command the rated limit (``limit / nominal gain``, at most the DAC's 10 V)
   for one period each way; the monitored current must reach the rated limit and not exceed
   it, both within ``limit_tolerance``. On jpl-arm the monitor's full scale equals the limit,
   so a current above it would read as the ADC's full scale: the upper check cannot see
   beyond ~100 %; the lower one catches a limit set too low.

H-bridge joints are skipped (their current is not commanded by a DAC).
"""

from __future__ import annotations

import numpy as np

from hal.adc_dac.conversions import DAC_V_MAX
from vmehil.calibration.base import CalibrationAbort, CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import CalibrationStore, JointCal, utc_now


def amp_nominal(joint) -> tuple[float, float, float]:
    """(gain A/V, monitor V/A, current limit A) from the rig's ``[joint.linear_amp]``."""
    t = joint.table.table("linear_amp", {})
    gain = t.get_float("gain_a_per_v", 1.0, min=1e-9)
    return gain, t.get_float("monitor_v_per_a", 1.0, min=1e-9), t.get_float("current_limit_a", gain * 10.0, min=0.0)


class AmplifierProcedure:
    name = "amplifier"
    version = 1
    title = "amplifiers: transconductance gain/offset (current monitor), current limit"

    gain_plausible = 0.05  #: |gain/nominal − 1|
    offset_limit_fraction = 0.01  #: |offset| ≤ 1 % of the current limit
    fit_residual_fraction = 0.005  #: fit residual ≤ 0.5 % of the current limit
    limit_tolerance = 0.05  #: monitored current at full command ≤ 105 % of the rated limit

    def __init__(self, levels: tuple[float, ...] = (0.05, 0.1, 0.2, 0.35, 0.5, 0.7), settle_s: float = 0.25) -> None:
        self.levels = levels
        self.settle_s = settle_s

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        joints = [ctx.rig.joints[i] for i in ctx.selected_joints()]
        todo = []
        for j in joints:
            if j.amplifier != "linear":
                res.skipped.append(f"{j.name}: {j.amplifier} amplifier (no transconductance to measure)")
            elif "imon" not in j.wiring:
                res.skipped.append(f"{j.name}: current monitor not wired")
            else:
                todo.append(j)
        if not todo:
            return res
        pos = ctx.positioner()
        res.data["joints"] = {}
        # Every joint's pulses at once: the joints are independent mechanisms, each amplifier on
        # its own DAC channel and monitor input, so each reads what it would alone — in one
        # series of pulses instead of one per joint.
        plan = []
        for j in todo:
            gain_n, mon, limit = amp_nominal(j)
            pin = j.wiring["imon"]
            full_v = min(DAC_V_MAX, limit / gain_n)
            plan.append((j, gain_n, mon, limit, pos.io.adc[pin.board], pin.index, full_v))
            ctx.say(f"  {j.name}: {2 * len(self.levels)} one-period pulses up to ±{self.levels[-1] * full_v:.2f} V")

        def pulse(fraction: float) -> dict[int, tuple[float, float]]:
            """Every joint commanded ``fraction`` of its full command for one period: (v, i) each."""
            for j, _g, _m, _l, _adc, _ch, full_v in plan:
                pos.override_command(j.index, fraction * full_v)
            pos.hold(pos.period_s)  # the pulse period
            reading: dict[int, tuple[float, float]] = {}

            def read() -> None:
                if not reading:
                    for j, _g, mon, _l, adc, ch, full_v in plan:
                        reading[j.index] = (fraction * full_v, adc.read_volts(ch) / mon)

            pos.hold(pos.period_s, on_tick=read)
            return reading

        series: list[dict[int, tuple[float, float]]] = []
        for k, frac in enumerate(self.levels):
            ctx.progress("amplifier pulses", k, len(self.levels))
            for sign in (1.0, -1.0):
                series.append(pulse(sign * frac))
            pos.hold(self.settle_s)
        peaks = [pulse(1.0), pulse(-1.0)]
        pos.hold(self.settle_s)
        ctx.progress("amplifier pulses", len(self.levels), len(self.levels))
        fault = pos.faulted()
        if fault:
            raise CalibrationAbort(f"the servo loop stopped during the amplifier pulses: {fault}")
        for j, gain_n, mon, limit, _adc, _ch, full_v in plan:
            cmds = [p[j.index][0] for p in series]
            amps = [p[j.index][1] for p in series]
            peak = [abs(p[j.index][1]) for p in peaks]
            cmds_a, amps_a = np.array(cmds), np.array(amps)
            gain, offset = np.polyfit(cmds_a, amps_a, 1)
            resid = float(np.max(np.abs(amps_a - np.polyval([gain, offset], cmds_a))))
            ctx.say(f"  {j.name}: gain {gain:.4f} A/V (nominal {gain_n:.4f}), offset {offset * 1e3:+.1f} mA, "
                    f"peak at full command {max(peak):.2f} A (limit {limit:.2f} A)")
            res.checks += [
                Check(f"{j.name} gain/nominal − 1", (gain / gain_n - 1) * 100, "%", self.gain_plausible * 100),
                Check(f"{j.name} offset", float(offset), "A", self.offset_limit_fraction * limit),
                Check(f"{j.name} fit residual", resid, "A", self.fit_residual_fraction * limit),
                Check(f"{j.name} current at full command", max(peak), "A", limit * (1 + self.limit_tolerance),
                      note="current limit: not exceeded"),
                Check(f"{j.name} current at full command (reached)", max(peak), "A",
                      min(limit, gain_n * full_v) * (1 - self.limit_tolerance), kind="min",
                      note="current limit: the rated current is delivered"),
            ]
            values = {"gain_a_per_v": float(gain), "offset_a": float(offset), "monitor_v_per_a": mon,
                      "current_limit_a": limit, "peak_current_a": float(max(peak))}
            update.set_joint(j.name, JointCal(self.name, self.version, utc_now(), values))
            res.data["joints"][j.name] = {**values, "commands_v": cmds, "currents_a": amps, "fit_residual_a": resid}
        return res
