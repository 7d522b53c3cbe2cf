"""The ADC/DAC calibration table (hal.adc_dac.calibration): the straight-line error model and its
inverse, worked by hand, and the refusals of a malformed table with their texts."""

from __future__ import annotations

import numpy as np
import pytest

from hal.adc_dac.calibration import Calibration, CalibrationError


def _refused(text: str) -> pytest.RaisesExc[CalibrationError]:
    return pytest.raises(CalibrationError, match=text)


def test_error_model_and_its_inverse_on_two_channels() -> None:
    cal = Calibration((0.01, -0.02), (1.1, 0.8))
    assert cal.channels == 2
    assert cal.apply(0, 2.0) == pytest.approx(2.21)  # 1.1·2 + 0.01
    assert cal.apply(1, 2.0) == pytest.approx(1.58)  # 0.8·2 − 0.02
    assert cal.correct(0, 2.21) == pytest.approx(2.0)
    assert cal.correct(1, 1.0) == pytest.approx(1.275)  # (1 + 0.02) / 0.8
    np.testing.assert_allclose(cal.correct_array([1, 0, 1], [1.0, 2.21, -0.02]), [1.275, 2.0, 0.0])
    assert cal.to_dict() == {"offset_v": [0.01, -0.02], "gain": [1.1, 0.8]}
    ident = Calibration.identity(3)
    assert (ident.offset_v, ident.gain) == ((0.0, 0.0, 0.0), (1.0, 1.0, 1.0))


def test_table_refuses_unequal_lengths_non_finite_offsets_and_bad_gains() -> None:
    with _refused(r"^calibration has 2 offsets but 1 gains; give one of each per channel$"):
        Calibration((0.0, 0.0), (1.0,))
    with _refused(r"^calibration channel 1: offset_v nan is not a finite number of volts$"):
        Calibration((0.0, float("nan")), (1.0, 1.0))
    with _refused(r"^calibration channel 1: offset_v inf is not"):
        Calibration((0.0, float("inf")), (1.0, 1.0))
    for bad in (0.0, -1.0, float("inf"), float("nan")):
        with _refused(rf"^calibration channel 1: gain {bad!r} must be a finite number > 0$"):
            Calibration((0.0, 0.0), (1.0, bad))
    assert Calibration((0.0,), (1e-9,)).gain == (1e-9,)


def test_from_dict_fills_an_omitted_key_with_the_identity() -> None:
    cal = Calibration.from_dict({"offset_v": [0.5, -0.25]})
    assert (cal.offset_v, cal.gain) == ((0.5, -0.25), (1.0, 1.0))
    cal = Calibration.from_dict({"gain": [2, 0.5]})  # ints taken as floats
    assert (cal.offset_v, cal.gain) == ((0.0, 0.0), (2.0, 0.5))
    assert isinstance(cal.gain[0], float)
    cal = Calibration.from_dict({}, channels=3)
    assert (cal.offset_v, cal.gain) == ((0.0,) * 3, (1.0,) * 3)
    cal = Calibration.from_dict({"offset_v": (0.1,), "gain": (1.5,)}, channels=1)
    assert (cal.offset_v, cal.gain) == ((0.1,), (1.5,))


def test_from_dict_refuses_a_malformed_table_naming_what_is_wrong() -> None:
    with _refused(r"^calibration has unknown keys \['bias', 'zero'\]; expected offset_v and gain$"):
        Calibration.from_dict({"zero": [0.0], "bias": [0.0], "gain": [1.0]})
    with _refused(r"^calibration has neither offset_v nor gain; cannot tell the channel count$"):
        Calibration.from_dict({})
    for key in ("offset_v", "gain"):
        for bad in ("1.0", 1.0, [1.0, "2"], [True], {"a": 1.0}):
            with _refused(rf"^calibration key '{key}': expected a list of numbers, got "):
                Calibration.from_dict({key: bad})
        with _refused(rf"^calibration key '{key}': expected 3 values \(one per channel\), got 2$"):
            Calibration.from_dict({key: [1.0, 1.0]}, channels=3)
    with _refused(r"^calibration key 'gain': expected 2 values \(one per channel\), got 1$"):
        Calibration.from_dict({"offset_v": [0.0, 0.0], "gain": [1.0]})
    with _refused(r"got \[1\.0, '2'\]$"):
        Calibration.from_dict({"gain": [1.0, "2"]})
