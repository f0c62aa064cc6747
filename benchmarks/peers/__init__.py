"""mink on exactly qpik's problems, for the benchmarks and the tests (not installed with
qpik): :mod:`.mink_mirror` writes a qpik problem (tasks, limits) as mink's, step for
step the same QP, and times mink's own loop; :mod:`.equivalence` rolls a problem out
with both, untimed, and reports how far their trajectories part.

``benchmarks/third_party.py`` times them; ``tests/app/test_third_party.py`` checks the
equivalence on shortened runs. (``qpik compare``'s peers, mink and placo on the bundled
scenarios, are the installed :mod:`qpik.app.peers`.)"""
