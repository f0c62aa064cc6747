"""The lab beside qpik: benchmark scripts (``python benchmarks/NAME.py``), their results
(``benchmarks/results/``), and the harness packages they and the tests share: the fuzzes
(:mod:`benchmarks.fuzz`) and mink's exact mirror of qpik's problems
(:mod:`benchmarks.peers`). None of it is installed with qpik."""
