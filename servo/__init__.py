"""The controller a real rig runs: the 125 Hz servo loop, joint I/O through the drivers, control
law and objects, gains and their guard, trajectories and motion, the runners, the watchdog and the
safe stop. It imports ``hal`` only (the command line and the tools are ``vmehil``'s)."""
