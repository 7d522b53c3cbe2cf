"""ADC and DAC boards: register maps, volts/code conversions, calibration and drivers."""

from hal.adc_dac.adc import AdcDriver, AdcError, AdcStatus, AdcTimeoutError
from hal.adc_dac.adc_regs import ADC_BOARD_ID, ADC_CHANNELS, ADC_REGMAP
from hal.adc_dac.calibration import Calibration, CalibrationError
from hal.adc_dac.conversions import AdcDacError, AdcRange, BoardIdError
from hal.adc_dac.dac import DacDriver, DacRangeError, DacWriteResult
from hal.adc_dac.dac_regs import DAC_BOARD_ID, DAC_CHANNELS, DAC_REGMAP
from hal.adc_dac.vmivme4116 import Vmi4116RangeError, VmiVme4116Driver, probe_vmivme4116
from hal.adc_dac.vmivme4116_regs import VMI4116_CHANNELS, VMI4116_REGMAP

__all__ = [
    "ADC_BOARD_ID",
    "ADC_CHANNELS",
    "ADC_REGMAP",
    "DAC_BOARD_ID",
    "DAC_CHANNELS",
    "DAC_REGMAP",
    "VMI4116_CHANNELS",
    "VMI4116_REGMAP",
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
    "Vmi4116RangeError",
    "VmiVme4116Driver",
    "probe_vmivme4116",
]
