"""Each calibration procedure recovers errors injected into the board emulators / the bench arm.

The bench (tests/support/calib_bench.py) is a rig built from board emulators with injected offset,
gain and non-linearity errors; procedures see only drivers, the positioner and the fixture.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from tests.support.calib_bench import Errors, build_bench
from vmehil.calibration.adc import AdcProcedure
from vmehil.calibration.amplifier import AmplifierProcedure
from vmehil.calibration.base import CalibrationAbort
from vmehil.calibration.dac import DacProcedure
from vmehil.calibration.encoder import EncoderProcedure
from vmehil.calibration.pot import ARCMIN_PER_RAD, PotProcedure, pot_targets
from vmehil.calibration.procedure_runner import procedure_results_table, resolve_procedure_names, run_procedures
from vmehil.calibration.store import load_store

ERRORS = Errors(
    adc1_offset_v=0.012, adc1_gain_error=0.004,
    dac_offset_v=(0.0,) * 6 + (-0.020, 0.015), dac_gain_error=(0.0,) * 6 + (0.003, -0.005),
    amp_gain=(3.09, 1.95), amp_offset_a=(0.05, -0.03),
)


def test_adc_recovers_injected_offset_and_gain(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    res = AdcProcedure().run(b.context())
    assert res.passed, procedure_results_table([res])
    cal = res.update.board_calibration("adc1")
    # stated tolerances: offset within 1.5 mV (0.3 LSB), gain within 0.05 %
    assert cal.offset_v[5] == pytest.approx(0.012, abs=1.5e-3)
    assert cal.gain[5] == pytest.approx(1.004, abs=5e-4)
    assert res.update.board_calibration("adc0") is None  # no references on adc0: left nominal
    assert any("adc0" in s for s in res.skipped)


def test_dac_recovers_per_channel_errors_with_the_calibrated_adc(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    ctx = b.context()
    out = run_procedures(ctx, ["adc", "dac"], out_path=None)
    assert out.passed, procedure_results_table(out.results)
    cal = ctx.store.board_calibration("dac0")
    # stated tolerances: offset within 2 mV, gain within 0.1 %
    assert cal.offset_v[6] == pytest.approx(-0.020, abs=2e-3)
    assert cal.offset_v[7] == pytest.approx(0.015, abs=2e-3)
    assert cal.gain[6] == pytest.approx(1.003, abs=1e-3)
    assert cal.gain[7] == pytest.approx(0.995, abs=1e-3)
    assert cal.offset_v[0] == 0.0 and cal.gain[0] == 1.0  # no loopback: nominal


def test_dac_without_adc_calibration_inherits_the_adc_error(tmp_path):
    """Measured through an uncalibrated ADC the DAC figures carry the ADC's 12 mV offset."""
    b = build_bench(tmp_path, ERRORS)
    res = DacProcedure().run(b.context())
    off = res.update.board_calibration("dac0").offset_v[6]
    assert abs(off - (-0.020)) > 0.008


def test_encoder_counts_per_rev_index_and_direction(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    res = EncoderProcedure().run(b.context())
    assert res.passed, procedure_results_table([res])
    e = res.update.joint_entry("j1", "encoder").values
    assert e["counts_per_motor_rev"] == 2000
    assert e["counts_per_joint_rev"] == 200000
    assert e["direction"] == 1
    # the index angle is a whole number of motor revolutions from the others
    caps = res.data["joints"]["j1"]["captures"]
    fwd = [c for c in caps if c[2] > 0]
    spacing = 2 * math.pi / 100
    assert (fwd[1][1] - fwd[0][1]) == pytest.approx(spacing, abs=spacing / 200)


def test_encoder_moves_every_joint_in_one_tour_each_at_its_own_motor_speed(tmp_path):
    """One forward and one backward move for all joints together (not one tour per joint), with
    a per-joint speed limit of ``speed`` motor rev/s; each joint's figures as if alone."""
    b = build_bench(tmp_path, ERRORS)
    calls: list[tuple[dict, object]] = []
    move_to = b.move_to

    def spy(targets, **kw):
        calls.append((dict(targets), kw.get("speed_rad_s")))
        return move_to(targets, **kw)

    b.move_to = spy  # type: ignore[method-assign]
    res = EncoderProcedure(speed_motor_rev_s=1.0).run(b.context())
    assert res.passed, procedure_results_table([res])
    assert [sorted(t) for t, _ in calls] == [[0, 1], [0, 1]]
    ratio = 100  # both bench joints
    for _targets, speed in calls:
        assert speed == {0: pytest.approx(2 * math.pi / ratio), 1: pytest.approx(2 * math.pi / ratio)}
    for name in ("j1", "j2"):
        assert res.update.joint_entry(name, "encoder").values["counts_per_motor_rev"] == 2000


def test_encoder_with_other_line_count_is_measured_not_assumed(tmp_path):
    b = build_bench(tmp_path, Errors(encoder_lines=(512, 500)))
    res = EncoderProcedure().run(b.context())
    e = res.update.joint_entry("j1", "encoder").values
    assert e["counts_per_motor_rev"] == 2048
    assert not res.passed  # 48 counts off the rig's nominal 2000
    failed = [c.item for c in res.checks if not c.passed]
    assert failed == ["j1 counts/rev − nominal 2000"]


def test_encoder_direction_check_fails_on_swapped_channels(tmp_path):
    b = build_bench(tmp_path, Errors(encoder_sign=(-1, 1)))
    res = EncoderProcedure().run(b.context())
    bad = [c for c in res.checks if "direction" in c.item and c.item.startswith("j1")]
    assert not bad[0].passed and "swap" in bad[0].note
    assert res.update.joint_entry("j1", "encoder").values["direction"] == -1


def test_amplifier_recovers_gain_offset_and_checks_limit(tmp_path):
    """Through the calibrated ADC (the monitor is read on adc1, which has a 0.4 % gain error)."""
    b = build_bench(tmp_path, ERRORS)
    ctx = b.context()
    out = run_procedures(ctx, ["adc", "amplifier"], out_path=None)
    assert out.passed, procedure_results_table(out.results)
    j1 = ctx.store.joint_entry("j1", "amplifier").values
    j2 = ctx.store.joint_entry("j2", "amplifier").values
    # stated tolerances: gain within 0.3 %, offset within 20 mA (monitor through a 12-bit ADC)
    assert j1["gain_a_per_v"] == pytest.approx(3.09, rel=3e-3)
    assert j1["offset_a"] == pytest.approx(0.05, abs=0.02)
    assert j2["gain_a_per_v"] == pytest.approx(1.95, rel=3e-3)
    assert j2["offset_a"] == pytest.approx(-0.03, abs=0.02)
    assert j1["peak_current_a"] <= 30.0 * 1.001


def test_amplifier_pulses_every_joint_together_in_one_series(tmp_path):
    """Each pulse overrides both joints' commands in the same period (one series for the arm,
    not one per joint), and each joint's fit is its own."""
    b = build_bench(tmp_path, ERRORS)
    overrides: list[tuple[int, int]] = []  # (bench tick, joint)
    override = b.override_command

    def spy(joint, volts):
        overrides.append((b.ticks, joint))
        return override(joint, volts)

    b.override_command = spy  # type: ignore[method-assign]
    res = AmplifierProcedure().run(b.context())
    ticks = sorted({t for t, _ in overrides})
    assert len(ticks) == 2 * len(AmplifierProcedure().levels) + 2  # ± each level, ± full command
    assert sorted(overrides) == sorted((t, j) for t in ticks for j in (0, 1))
    j1, j2 = (res.update.joint_entry(n, "amplifier").values for n in ("j1", "j2"))
    assert j1["gain_a_per_v"] == pytest.approx(3.09, rel=1e-2)
    assert j2["gain_a_per_v"] == pytest.approx(1.95, rel=1e-2)


def test_amplifier_limit_check_fails_when_the_limit_is_set_too_low(tmp_path):
    b = build_bench(tmp_path, Errors(amp_limit_a=(20.0, 20.0)))
    res = AmplifierProcedure().run(b.context())
    failed = {c.item: c for c in res.checks if not c.passed}
    assert "j1 current at full command (reached)" in failed  # (the clipped top level also spoils the fit)
    assert failed["j1 current at full command (reached)"].value == pytest.approx(20.0, rel=0.01)
    assert all(c.passed for c in res.checks if c.item.startswith("j2"))


def test_pot_targets_follow_the_paper_and_fit_the_travel():
    t = pot_targets(-math.radians(185), math.radians(185))
    assert len(t) == 9 and np.allclose(np.diff(t), math.radians(45))
    short = pot_targets(-0.35, 1.9)
    assert len(short) == 9 and short[0] == pytest.approx(-0.35) and short[-1] == pytest.approx(1.9)


def test_pot_residual_after_calibration_is_below_the_stated_figure(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    res = PotProcedure().run(b.context())
    assert res.passed, procedure_results_table([res])
    for name in ("j1", "j2"):
        d = res.data["joints"][name]
        assert d["before_rms_arcmin"] > 30.0  # the injected ~1° bow
        assert d["residual_rms_arcmin"] < PotProcedure.residual_rms_limit_arcmin
        assert d["residual_max_arcmin"] < PotProcedure.residual_max_limit_arcmin
        assert len(d["points"]) == 9
    for key in ("points", "before_rms_arcmin", "residual_rms_arcmin", "residual_max_arcmin"):
        assert key in res.data
    # the table maps pot volts to the true angle at its own points
    j1 = res.update.joint_entry("j1", "pot").values
    assert len(j1["volts"]) == 9 and np.all(np.diff(j1["angles_rad"]) > 0)


def test_pot_ripple_that_eight_segments_cannot_follow_fails_and_more_points_fix_it(tmp_path):
    """A coarse winding ripple (8 arcmin at a 68° period) defeats nine points on a 324° travel."""
    harsh = Errors(pot_periodic=(0.0004, 0.0004), pot_cycles=5.0)
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    nine = PotProcedure().run(build_bench(tmp_path / "a", harsh).context(joints=[0]))
    seventeen = PotProcedure(points=17).run(build_bench(tmp_path / "b", harsh).context(joints=[0]))
    assert not nine.passed
    assert nine.data["residual_rms_arcmin"] > PotProcedure.residual_rms_limit_arcmin
    assert seventeen.data["residual_rms_arcmin"] < 0.6 * nine.data["residual_rms_arcmin"]


def test_pot_manual_mode_prompts_the_operator(tmp_path):
    b = build_bench(tmp_path, Errors(pot_noise_v=0.0))
    answers: list[str] = []

    def prompt(text: str) -> str:  # the operator reads the angle off the level: the bench's true angle
        j = 0 if "j1" in text else 1
        answers.append(text)
        return f"{math.degrees(b.theta[j]):.4f}"

    ctx = b.context(joints=[0], prompt=prompt)
    ctx.auto = False
    ctx.fixture = None
    res = PotProcedure(verify_per_segment=0).run(ctx)
    assert len(answers) == 9
    assert res.update.joint_entry("j1", "pot").values["angles_rad"][0] == pytest.approx(b.theta[0] - 8 * math.radians(
        40.5), abs=1e-3)


def test_pot_operator_abort_raises(tmp_path):
    b = build_bench(tmp_path)
    ctx = b.context(joints=[1], prompt=lambda text: "q")
    ctx.auto = False
    with pytest.raises(CalibrationAbort, match="aborted"):
        PotProcedure(verify_per_segment=0).run(ctx)


def test_all_runs_in_order_and_writes_a_file_the_drivers_apply(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    ctx = b.context()
    path = tmp_path / "cal.toml"
    out = run_procedures(ctx, resolve_procedure_names("all"), out_path=path)
    assert out.passed, procedure_results_table(out.results)
    assert [r.procedure for r in out.results] == ["adc", "dac", "encoder", "amplifier", "pot"]
    store = load_store(path, b.rig, bus=b.crate)
    # drivers apply it: a fresh JointIO on the same crate reads the 5 V reference as 5 V
    from servo.io import JointIO

    io = JointIO(b.crate, b.rig, b.io.scaling, calibration=store)
    raw = b.context().adc("adc1", calibrated=False)
    assert abs(np.mean([raw.read_volts(12) for _ in range(32)]) - 5.0) > 0.02
    assert np.mean([io.adc["adc1"].read_volts(12) for _ in range(32)]) == pytest.approx(5.0, abs=1.5e-3)
    assert io.pot_cal[0].volts.tolist() == store.joint_entry("j1", "pot").values["volts"]
    assert io.scaling[0].amp_gain_a_per_v == pytest.approx(3.09, rel=3e-3)
    # the amplifier command now produces the wanted current: 10 A → (10 − 0.05)/3.09 V
    io.write_torque(np.array([10.0 * 100 * 1.0, 0.0]))
    assert io.last_dac_volts[0] == pytest.approx((10.0 - 0.05) / 3.09, rel=5e-3)
    # the pot now reads the true angle to within the stated residual
    m = io.read()
    assert abs(m.theta_pot[0] - b.theta[0]) * ARCMIN_PER_RAD < PotProcedure.residual_max_limit_arcmin


def test_a_failing_procedure_writes_nothing(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    path = tmp_path / "cal.toml"
    path.write_text("old")

    class Boom:
        name, version, title = "boom", 1, "explodes"

        def run(self, ctx):
            raise CalibrationAbort("wiper open")

    out = run_procedures(b.context(), ["adc", "pot"], out_path=path, factories={"pot": Boom})
    assert out.error and "wiper open" in out.error
    assert path.read_text() == "old"


def test_failed_checks_do_not_overwrite_unless_asked(tmp_path):
    b = build_bench(tmp_path, Errors(encoder_sign=(-1, 1)))
    path = tmp_path / "cal.toml"
    out = run_procedures(b.context(), ["encoder"], out_path=path)
    assert not out.passed and not path.exists()
    out = run_procedures(b.context(), ["encoder"], out_path=path, write_on_fail=True)
    assert path.exists()


def test_the_written_message_claims_a_prev_only_when_one_was_kept(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    path = tmp_path / "cal.toml"
    said: list[str] = []
    for _ in range(2):
        ctx = b.context()
        ctx.say = said.append
        out = run_procedures(ctx, ["adc"], out_path=path)
    first, second = [s for s in said if s.startswith("calibration written")]
    assert "previous kept" not in first and "no previous file" in first
    assert "previous kept as cal.toml.prev" in second and out.previous == tmp_path / "cal.toml.prev"
    assert out.previous.exists()


def test_all_runs_the_converters_first_and_not_friction():
    assert resolve_procedure_names("all") == ["adc", "dac", "encoder", "amplifier", "pot"]
    with pytest.raises(ValueError, match="unknown calibration procedure"):
        resolve_procedure_names("frobnicate")


class _NoEntries:
    """A procedure that measures and passes but writes no calibration entry (as ``friction``)."""

    name, version, title = "noentries", 1, "measures only"

    def run(self, ctx):
        from vmehil.calibration.base import ProcedureResult

        return ProcedureResult(self.name, self.version)


def test_a_procedure_without_entries_creates_no_header_only_file(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    path = tmp_path / "cal.toml"
    ctx = b.context()
    said: list[str] = []
    ctx.say = said.append
    out = run_procedures(ctx, ["pot"], out_path=path, factories={"pot": _NoEntries})
    assert out.passed and out.unchanged and out.written is None
    assert not path.exists() and not (tmp_path / "cal.toml.prev").exists()
    assert any("not created" in s for s in said)


def test_a_procedure_without_entries_leaves_an_existing_file_byte_for_byte(tmp_path):
    b = build_bench(tmp_path, ERRORS)
    path = tmp_path / "cal.toml"
    assert run_procedures(b.context(), ["adc"], out_path=path).written == path
    before = path.read_bytes()
    ctx = b.context()  # the bench's store now holds what the file holds
    ctx.store = load_store(path, ctx.rig)
    out = run_procedures(ctx, ["pot"], out_path=path, factories={"pot": _NoEntries})
    assert out.unchanged and out.written is None
    assert path.read_bytes() == before and not (tmp_path / "cal.toml.prev").exists()
    # and a procedure that does change an entry still writes
    ctx = b.context()
    ctx.store = load_store(path, ctx.rig)
    assert run_procedures(ctx, ["encoder"], out_path=path).written == path
    assert path.read_bytes() != before
