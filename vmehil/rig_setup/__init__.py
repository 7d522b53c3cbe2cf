"""Setting up the rig a command runs: the emulated rig (``system``), the servo loop from the
servo's settings (``session``; :mod:`servo.assembly` builds it), the drivers on a real VME
bus (``real_bus``), and what calibration procedures need of an emulated rig
(``emulated_calibration``)."""
