"""Linear and describing-function analysis of the normalized joint servo loop.

* :mod:`vmehil.analysis.loop_model`: the continuous and exactly sampled loop models (python-control);
* :mod:`vmehil.analysis.margins`: gain/phase margins, crossover, bandwidth;
* :mod:`vmehil.analysis.describing`: describing-function limit-cycle prediction;
* :mod:`vmehil.analysis.rigparams`: the loop and nonlinearity parameters of a rig's joint;
* :mod:`vmehil.analysis.simulate`: full-stack simulations (limit cycle, step, move) of a joint;
* :mod:`vmehil.analysis.sweep`: gain sweeps, parallel, with an executor seam;
* :mod:`vmehil.analysis.report`: JSON, plots and markdown for ``vmehil tune``.
"""
