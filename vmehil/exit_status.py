"""Exit statuses of every ``vmehil`` command (docs/faults.md, "Exit statuses")."""

EXIT_OK = 0
EXIT_FAULT = 1  #: a fault safe-stopped the run (the report says which)
EXIT_CHECK_FAILED = 1  #: ``calibrate``: a check failed; ``reproduce``: a figure left the paper's band
EXIT_USAGE = 2  #: bad input: a flag, a file, a key (nothing moved)
EXIT_UNEXPECTED = 3  #: an unexpected error (``--debug`` or VMEHIL_DEBUG=1 shows the traceback)
EXIT_STOP_INCOMPLETE = 4  #: a safe stop whose read-back could not confirm every output safe
# 130 / 143: ended by SIGINT / SIGTERM (128 + the signal number), after a safe stop
EXIT_BROKEN_PIPE = 141  #: stdout closed by its reader (``vmehil crate list | head``): 128 + SIGPIPE, as a shell tool
