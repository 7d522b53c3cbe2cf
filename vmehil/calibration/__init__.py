"""Calibration procedures and the calibration store (see ``docs/calibration.md``).

``vmehil.calibration.store`` (the file format) has no dependency on the procedures, so the
drivers' I/O layer can load calibrations without importing them.
:data:`vmehil.calibration.procedures.PROCEDURES` is the table of procedures: the built-in ones
(``adc``, ``dac``, ``encoder``, ``amplifier``, ``pot``) and the entry points of group
``vmehil.calibration_procedures`` (the plant's ``friction`` among them). This package is built
below the rig (:mod:`vmehil.rig_setup.system` loads the store); what runs procedures on an emulated rig is
:mod:`vmehil.rig_setup.emulated_calibration`.
"""
