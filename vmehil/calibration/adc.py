"""``vmehil calibrate adc``: ADC offset and gain from the reference inputs, checked over the
range with the DAC → ADC loopback.

Method, per ADC board:

1. Read every reference input of the board (``[rig.references]``, e.g. adc1:12 = +5.000 V,
   adc1:13 = 0 V) ``samples`` times with the raw driver (no calibration) and average.
2. Fit ``reading = gain · reference + offset_v`` by least squares over the references (at
   least two distinct levels are needed). A multiplexed board has one PGA and one converter,
   so the fit is the board's error and is written to all 16 channels; the channels actually
   measured are listed in the store (``measured``). Channel-to-channel mismatch is not
   observable without a reference on every channel: the pot channels are calibrated end to end
   by ``calibrate pot``.
3. Linearity check over the range: sweep each loopback DAC output (raw codes, −9..+9 V) into
   its ADC channel, correct with the new calibration and fit a straight line; the largest
   deviation from it (integral non-linearity, INL) must stay within ``inl_limit_lsb``.

Boards with no reference input are skipped (reported, not failed).
"""

from __future__ import annotations

import numpy as np

from hal.adc_dac.calibration import Calibration
from hal.adc_dac.conversions import AdcRange, adc_lsb
from vmehil.calibration.base import CalibrationContext, Check, ProcedureResult
from vmehil.calibration.store import BoardCal, CalibrationStore, rig_boards, utc_now

LSB_V = adc_lsb(AdcRange.BIPOLAR_10V, 1)  #: 4.8828 mV, ±10 V range at PGA gain 1


def average_volts(adc, channel: int, samples: int) -> float:
    """Mean of ``samples`` conversions of ``channel`` (volts, the driver's calibration applied),
    each made after the call: every read waits the driver's ``fresh_after_s`` first (0 for a board
    that converts on each read; an autoscanning board's scan, whose reads would otherwise show a
    code from before a DAC step, or one code again and again)."""
    wait = adc.fresh_after_s
    values = []
    for _ in range(samples):
        if wait > 0:
            adc.bus.delay(wait)
        values.append(adc.read_volts(channel))
    return float(np.mean(values))


class AdcProcedure:
    name = "adc"
    version = 1
    title = "ADC offset and gain (reference inputs; loopback linearity)"

    # Tolerances: the fit must reproduce the references to a quarter LSB; the errors found
    # must be plausible for a working board; the loopback sweep must be straight to 1 LSB.
    ref_residual_limit_v = 0.3 * LSB_V
    offset_plausible_v = 0.050
    gain_plausible = 0.02
    inl_limit_lsb = 1.0

    def __init__(self, samples: int = 64) -> None:
        self.samples = samples

    def run(self, ctx: CalibrationContext) -> ProcedureResult:
        update = CalibrationStore.empty(ctx.rig)
        res = ProcedureResult(self.name, self.version, update=update)
        idents = rig_boards(ctx.rig)
        boards = ctx.boards_of("adc")
        res.data["boards"] = {}
        for bi, board in enumerate(boards):
            ctx.progress(f"adc {board}", bi, len(boards))
            refs = sorted((p.index, v) for p, v in ctx.rig.references.items() if p.board == board)
            if len({round(v, 6) for _, v in refs}) < 2:
                res.skipped.append(f"{board}: fewer than two reference levels wired ([rig.references]); nominal")
                ctx.say(f"  {board}: no references wired — left nominal (pot channels are calibrated end to end)")
                continue
            raw = ctx.adc(board, calibrated=False)
            ctx.say(f"  {board}: reading {len(refs)} reference inputs, {self.samples} conversions each")
            volts = np.array([v for _, v in refs])
            reads = np.array([average_volts(raw, ch, self.samples) for ch, _ in refs])
            gain, offset = np.polyfit(volts, reads, 1)
            cal = Calibration((float(offset),) * raw.CHANNELS, (float(gain),) * raw.CHANNELS)
            # Re-read the references through the new calibration (fresh conversions): what is
            # left is noise and quantization; a drifting or noisy reference shows here.
            raw.calibration = cal
            resid = np.array([average_volts(raw, ch, self.samples) for ch, _ in refs]) - volts
            ctx.say(f"  {board}: gain {gain:.5f}, offset {offset * 1e3:+.2f} mV")
            res.checks += [
                Check(f"{board} offset", float(offset) * 1e3, "mV", self.offset_plausible_v * 1e3,
                      note="plausible for a working board"),
                Check(f"{board} gain error", (float(gain) - 1.0) * 100, "%", self.gain_plausible * 100),
                Check(f"{board} reference residual", float(np.max(np.abs(resid))) * 1e3, "mV",
                      self.ref_residual_limit_v * 1e3, note="corrected reference vs its value"),
            ]
            info = {"offset_v": float(offset), "gain": float(gain), "references": [
                {"channel": ch, "volts": v, "reading_v": float(r)} for (ch, v), r in zip(refs, reads, strict=True)]}
            inl = self._loopback_inl(ctx, board, cal)
            for ch, worst in inl.items():
                res.checks.append(Check(f"{board}:{ch} loopback INL", worst / LSB_V, "LSB", self.inl_limit_lsb))
            info["loopback_inl_lsb"] = {str(ch): w / LSB_V for ch, w in inl.items()}
            res.data["boards"][board] = info
            update.set_board(BoardCal(idents[board], cal, self.name, self.version, utc_now(),
                                          tuple(ch for ch, _ in refs)))
        ctx.progress("adc", len(boards), len(boards))
        return res

    def _loopback_inl(self, ctx: CalibrationContext, board: str, cal: Calibration) -> dict[int, float]:
        """Worst deviation (V) from a straight line of each loopback channel of ``board``."""
        out: dict[int, float] = {}
        pairs = [(d, a) for d, a in ctx.rig.loopback.items() if a.board == board]
        if not pairs:
            return out
        adc = ctx.adc(board, calibrated=False)
        adc.calibration = cal
        for dpin, apin in pairs:
            dac = ctx.dac(dpin.board, calibrated=False)
            cmds = np.linspace(-9.0, 9.0, 13)
            reads = []
            for v in cmds:
                dac.write_volts(dpin.index, float(v))
                ctx.bus.delay(100e-6)  # DAC settling (10 µs) with margin
                reads.append(average_volts(adc, apin.index, max(8, self.samples // 4)))
            dac.write_volts(dpin.index, 0.0)
            fit = np.polyval(np.polyfit(cmds, reads, 1), cmds)
            out[apin.index] = float(np.max(np.abs(np.asarray(reads) - fit)))
            ctx.say(f"  {board}:{apin.index} ← {dpin}: loopback sweep INL {out[apin.index] / LSB_V:.2f} LSB")
        return out
