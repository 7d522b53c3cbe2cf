"""The faults of a run: a scenario parsed and injected through the rig's wiring, the stop
report (``injection``) and the ``--fault``/``--faults`` options (``options``);
docs/faults.md."""
