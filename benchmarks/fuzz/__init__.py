"""The fuzzes of qpik's promises: the lab beside the library, not part of the package.

- the bundled robots' fuzz (:mod:`.bundled`: random arm and hexapod rollouts and mutated
  scenes; :mod:`.bundled_sweep` runs and summarises them), whose command line is
  ``benchmarks/fuzz_bundled.py``;
- the any-robot fuzz (:mod:`.models` draws the models, :mod:`.cases` builds a case from
  its seed, rolls it out and classifies every returned step, :mod:`.checks` holds the
  independent checks: hard rows, limits, an LP for feasibility; :mod:`.sweep` runs and
  summarises them with a determinism repeat), whose command line is
  ``benchmarks/fuzz_any_robot.py``;
- :mod:`.pool`, the one pool of worker processes both run their cases in.

The tests (``tests/fuzz/``) run short versions. The any-robot fuzz's LP (the independent
reference) is SciPy's, a dependency of qpik; its third-party models need the ``models``
extra. Imported from the repository's root (``benchmarks`` is a package there).
"""
