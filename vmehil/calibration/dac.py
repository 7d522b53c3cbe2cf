"""``vmehil calibrate dac``: per-channel DAC offset and gain measured with the calibrated ADC.

Method, per loopback pair ``[rig.loopback]`` (e.g. dac0:6 → adc1:14):

1. Write raw commands (no DAC calibration) at 13 levels from −9 V to +9 V; after settling,
   read the looped-back ADC channel ``samples`` times with the ADC calibration in force
   (run ``calibrate adc`` first) and average.
2. Fit ``actual = gain · commanded + offset_v`` (least squares); the residual is the DAC's
   integral non-linearity.
3. Verify: write the same levels through a driver with the new calibration; the measured
   output must match the wanted volts within ``verify_limit_v``.

DAC channels without a loopback (the amplifier commands) keep nominal values here: their
errors are part of the end-to-end amplifier gain and offset (``calibrate amplifier``).
"""

from __future__ import annotations

import numpy as np

from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import DAC_LSB_V
from vmehil.calibration.adc import average_volts
from vmehil.calibration.base import CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import BoardCal, CalibrationStore, rig_boards, utc_now


class DacProcedure:
    name = "dac"
    version = 1
    title = "DAC offset and gain (loopback into the calibrated ADC)"

    offset_plausible_v = 0.050
    gain_plausible = 0.02
    inl_limit_lsb = 1.0
    verify_limit_v = 0.5 * DAC_LSB_V + 0.0015  #: half a DAC LSB plus the ADC calibration's uncertainty

    def __init__(self, samples: int = 32) -> None:
        self.samples = samples

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        idents = rig_boards(ctx.rig)
        if not ctx.rig.loopback:
            res.skipped.append("no [rig.loopback] wiring: DAC left nominal")
            ctx.say("  no DAC → ADC loopback wired: nothing to measure")
            return res
        for a in ctx.rig.loopback.values():
            if ctx.store.board_calibration(a.board) is None:
                ctx.say(f"  warning: {a.board} has no calibration in force; DAC figures inherit its errors "
                        "(run calibrate adc first)")
        res.data["channels"] = {}
        by_board: dict[str, dict[int, tuple[float, float]]] = {}
        pairs = sorted(ctx.rig.loopback.items(), key=lambda kv: str(kv[0]))
        cmds = np.linspace(-9.0, 9.0, 13)
        for k, (dpin, apin) in enumerate(pairs):
            ctx.progress("dac", k, len(pairs))
            ctx.say(f"  {dpin} → {apin}: sweeping {len(cmds)} levels, {self.samples} conversions each")
            adc = ctx.adc(apin.board, calibrated=True)
            raw = ctx.dac(dpin.board, calibrated=False)
            actual = np.array([self._measure(ctx, raw, dpin.index, adc, apin.index, v) for v in cmds])
            gain, offset = np.polyfit(cmds, actual, 1)
            inl = float(np.max(np.abs(actual - np.polyval([gain, offset], cmds))))
            by_board.setdefault(dpin.board, {})[dpin.index] = (float(offset), float(gain))
            # verify through a calibrated driver
            cal_drv = ctx.dac(dpin.board, calibrated=False)
            cal_drv.calibration = _board_cal(by_board[dpin.board], cal_drv.CHANNELS)
            check_v = np.array([-8.0, -2.5, 0.0, 2.5, 8.0])
            got = np.array([self._measure(ctx, cal_drv, dpin.index, adc, apin.index, v) for v in check_v])
            verify = float(np.max(np.abs(got - check_v)))
            raw.write_volts(dpin.index, 0.0)
            ctx.say(f"  {dpin}: gain {gain:.5f}, offset {offset * 1e3:+.2f} mV, INL {inl / DAC_LSB_V:.2f} LSB, "
                    f"verified within {verify * 1e3:.2f} mV")
            res.checks += [
                Check(f"{dpin} offset", float(offset) * 1e3, "mV", self.offset_plausible_v * 1e3),
                Check(f"{dpin} gain error", (float(gain) - 1) * 100, "%", self.gain_plausible * 100),
                Check(f"{dpin} INL", inl / DAC_LSB_V, "LSB", self.inl_limit_lsb),
                Check(f"{dpin} calibrated output error", verify * 1e3, "mV", self.verify_limit_v * 1e3),
            ]
            res.data["channels"][str(dpin)] = {"adc": str(apin), "offset_v": float(offset), "gain": float(gain),
                                               "inl_lsb": inl / DAC_LSB_V, "verify_error_v": verify}
        ctx.progress("dac", len(pairs), len(pairs))
        for board, chans in by_board.items():
            cal = _board_cal(chans, 8)
            update.set_board(BoardCal(idents[board], cal, self.name, self.version, utc_now(), tuple(sorted(chans))))
        return res

    def _measure(self, ctx: CalibrationContext, dac, dch: int, adc, ach: int, volts: float) -> float:
        dac.write_volts(dch, float(volts))
        ctx.bus.delay(100e-6)  # settling: 10 µs nominal, with margin
        return average_volts(adc, ach, self.samples)


def _board_cal(chans: dict[int, tuple[float, float]], n: int) -> Calibration:
    offs = [chans.get(c, (0.0, 1.0))[0] for c in range(n)]
    gains = [chans.get(c, (0.0, 1.0))[1] for c in range(n)]
    return Calibration(tuple(offs), tuple(gains))
