"""ADC and DAC boards: register maps, volts/code conversions, calibration and drivers."""

from hal.adc_dac.adc import AdcDriver, AdcError, AdcStatus, AdcTimeoutError
from hal.adc_dac.adc_regs import ADC_BOARD_ID, ADC_CHANNELS, ADC_REGMAP
from hal.adc_dac.calibration import Calibration, CalibrationError
from hal.adc_dac.conversions import AdcDacError, AdcRange, BoardIdError
from hal.adc_dac.dac import DacDriver, DacRangeError, DacWriteResult
from hal.adc_dac.dac_regs import DAC_BOARD_ID, DAC_CHANNELS, DAC_REGMAP

__all__ = [
    "ADC_BOARD_ID",
    "ADC_CHANNELS",
    "ADC_REGMAP",
    "DAC_BOARD_ID",
    "DAC_CHANNELS",
    "DAC_REGMAP",
    "AdcDacError",
    "AdcDriver",
    "AdcError",
    "AdcRange",
    "AdcStatus",
    "AdcTimeoutError",
    "BoardIdError",
    "Calibration",
    "CalibrationError",
    "DacDriver",
    "DacRangeError",
    "DacWriteResult",
]
