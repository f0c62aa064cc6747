"""The repository's tools beside qpik (not installed with it): :mod:`tools.results`
generates docs/results.md from the benchmarks' recordings, with the tables of
:mod:`tools.tables` and the scenario rows of :mod:`tools.scenarios_table`."""
