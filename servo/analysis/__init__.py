"""Linear and describing-function analysis of the normalized joint servo loop.

* :mod:`servo.analysis.loop`: the continuous and exactly sampled loop models (python-control);
* :mod:`servo.analysis.margins`: gain/phase margins, crossover, bandwidth;
* :mod:`servo.analysis.describing`: describing-function limit-cycle prediction;
* :mod:`servo.analysis.rigparams`: the loop and nonlinearity parameters of a rig's joint;
* :mod:`servo.analysis.simulate`: full-stack simulations (limit cycle, step, move) of a joint;
* :mod:`servo.analysis.sweep`: gain sweeps, parallel, with an executor seam;
* :mod:`servo.analysis.report`: JSON, plots and markdown for ``vmehil tune``.
"""
