"""Calibration procedures and the calibration store (see ``docs/calibration.md``).

``vmehil.calibration.store`` (the file format) has no dependency on the procedures, so the
drivers' I/O layer can load calibrations without importing them. Importing
:mod:`vmehil.calibration.procedures` registers the built-in procedures (``adc``, ``dac``,
``encoder``, ``amplifier``, ``pot``); others (the plant's ``friction``) register with
:func:`vmehil.calibration.base.register_procedure`.
"""
