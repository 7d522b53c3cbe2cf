"""Reports of runs: the report directory (``run_report``) and the figures of merit it gives
(``metrics``)."""
