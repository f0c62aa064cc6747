"""Every bundled scenario's final configuration, for every controller, equals the one
recorded before the package layout moved (tests/data/baseline_q_final.json, produced at
commit 3767d08 with MuJoCo 4.0.0): refactors and speed work must not change results.

Exact solvers and the closed-form laws must agree to 1e-12; tolerance-based solvers
(OSQP, ProxQP) stop on a residual, so a reordering of floating-point work may move their
answer within their tolerance: 1e-8. The classical law on hexapod-stroke-limits jams
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
    tolerance = 1e-12 if solver in EXACT else 1e-8
    np.testing.assert_allclose(log.q[-1], expected["q_final"], rtol=0, atol=tolerance)
