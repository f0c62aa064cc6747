"""Every bundled scenario's final configuration, for every controller, equals the one
recorded before the package layout moved (tests/data/baseline_q_final.json, produced at
commit 3767d08 with MuJoCo 4.0.0): refactors and speed work must not change results.

The QP's solution does not depend on the solver that finds it: the exact solvers (DAQP,
quadprog) and the closed-form laws must give the recorded DAQP / classical-law final q to
1e-12. Tolerance-based solvers (OSQP, ProxQP) stop on a residual, and since the
controller's closed-form fast path now returns the exact solution on every step where no
limit binds, they are compared with their own recording to 1e-6 (their answers were off
by their tolerance on those steps). The classical law on hexapod-stroke-limits jams
chaotically (a rounding difference changes which steps jam; it changed with the MuJoCo
version and may with the CPU's SIMD kernels), so only its length is compared."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from qpik.app.runs import run

BASELINE = json.loads((Path(__file__).parents[1] / "data" / "baseline_q_final.json").read_text())
EXACT = {"daqp", "quadprog", "none"}
ROBOT = {"hexapod-circle": "hexapod", "hexapod-stroke-limits": "hexapod", "hexapod-position-only": "hexapod"}


@pytest.mark.parametrize("key", sorted(BASELINE))
def test_final_configuration_unchanged(key):
    scenario, controller, solver, mode = key.split("/")
    _, log = run(ROBOT.get(scenario, "arm"), scenario, controller, "daqp" if solver == "none" else solver, mode,
                 on_failure="stop")
    expected = BASELINE[key]
    assert len(log.t) == expected["steps"]
    if key.startswith("hexapod-stroke-limits/pinv/"):
        return
    if solver in EXACT:
        reference = BASELINE[f"{scenario}/{controller}/{'daqp' if controller == 'qp' else solver}/{mode}"]
        np.testing.assert_allclose(log.q[-1], reference["q_final"], rtol=0, atol=1e-12)
    else:
        np.testing.assert_allclose(log.q[-1], expected["q_final"], rtol=0, atol=1e-6)
