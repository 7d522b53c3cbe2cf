"""Looking inside a running loop (docs/scope.md): the one signal catalog and its SPEC grammar
(:mod:`~vmehil.scope.catalog`), where each signal is observed without adding a bus cycle
(:mod:`~vmehil.scope.sources`), one writer per file format (:mod:`~vmehil.scope.mcap_writer`,
:mod:`~vmehil.scope.vcd_writer`, :mod:`~vmehil.scope.table_writer`), the trace that feeds them
tick by tick within a size bound (:mod:`~vmehil.scope.trace`) and the plot of a trace file
(:mod:`~vmehil.scope.show`)."""
