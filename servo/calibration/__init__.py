"""Calibration procedures and the calibration store (see ``docs/calibration.md``).

``servo.calibration.store`` (the file format) has no dependency on the procedures, so the
drivers' I/O layer can load calibrations without importing them. Importing
:mod:`servo.calibration.procedures` registers the built-in procedures (``adc``, ``dac``,
``encoder``, ``amplifier``, ``pot``); others (the plant's ``friction``) register with
:func:`servo.calibration.base.register_procedure`.
"""
