"""vmehil, the application: the ``vmehil`` command, rig assembly (emulated or real), tuning
analysis, calibration procedures and their store, friction identification, the operator console,
MAVLink, reports and sweeps. It may import ``hal``, ``emulators`` and ``servo``; nothing imports it."""
