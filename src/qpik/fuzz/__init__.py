"""The any-robot fuzz: random and third-party models, every task, limit and controller.

:mod:`qpik.fuzz.models` draws the models, :mod:`qpik.fuzz.cases` builds a case from its
seed, rolls it out and classifies every returned step, :mod:`qpik.fuzz.checks` holds the
independent checks (hard rows, limits, an LP for feasibility) and :mod:`qpik.fuzz.sweep`
runs cases in chunks of worker processes with a hang detector and a determinism repeat.
The benchmark ``benchmarks/fuzz_any_robot.py`` runs the full sweep; the test suite a
short one. Needs SciPy (its LP is the independent reference; the ``test`` extra) and,
for the third-party models, the ``models`` extra.
"""

from ..extras import require

require("scipy", "qpik.fuzz (its LP is the independent feasibility reference)", extra="test")

from .cases import CLASSES, DEFECTS, run_case

__all__ = ["CLASSES", "DEFECTS", "run_case"]
