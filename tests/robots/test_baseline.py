"""Every bundled scenario's final configuration, for every controller, equals the one
recorded before the package layout moved (tests/data/baseline_q_final.json, produced at
commit 3767d08 with MuJoCo 4.0.0): refactors and speed work must not change results.

The QP's solution does not depend on the solver that finds it: every solver and the
closed-form laws must give the recorded DAQP / classical-law final q to the rounding a
rollout accumulates (``rounding_tolerance``: the recording came from another CPU and BLAS
kernel, whose rounding differs). The tolerance-based solvers (OSQP, ProxQP) stop on a
residual, but their answers are polished to the minimiser (the held-bounds iteration from
the bounds they are on), and the closed form answers the steps where no limit binds; their
own recordings, made before the polish, were off by up to 1.3e-5. The classical law on hexapod-stroke-limits jams
chaotically (a rounding difference changes which steps jam; it changed with the MuJoCo
version and may with the CPU's SIMD kernels), so only its length is compared."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import mujoco

from qpik.app.runs import run

BASELINE = json.loads((Path(__file__).parents[1] / "data" / "baseline_q_final.json").read_text())
ROBOT = {"hexapod-circle": "hexapod", "hexapod-stroke-limits": "hexapod", "hexapod-position-only": "hexapod"}


def rounding_tolerance(setup, log) -> float:
    """How far two CPUs' roundings can move a rollout's final q: N · ε · κ · max(1, |q|∞).

    Each step rounds the integrated q ← q ⊕ q̇Δt at ε|q|. The task errors are fed back
    every step (KΔt = 1 on these scenarios), so rounding in task directions does not
    build up, but in the null space and in the passive joints nothing pulls it back: over
    N steps it can add up to N · ε|q|. The passive joints are placed on the loop closures,
    which amplify a rounding by the condition number κ of the loops' constraint Jacobian
    (about 26 on the hexapod; 1 on the arm, which has no loop)."""
    model = setup.robot.model
    data = mujoco.MjData(model)
    data.qpos[:] = log.q[-1]
    mujoco.mj_forward(model, data)
    kappa = 1.0
    if data.nefc:
        singular = np.linalg.svd(data.efc_J.reshape(data.nefc, model.nv), compute_uv=False)
        kappa = max(1.0, singular[0] / singular[singular > 1e-12 * singular[0]][-1])
    return len(log.t) * np.finfo(float).eps * kappa * max(1.0, np.max(np.abs(log.q[-1])))


@pytest.mark.parametrize("key", sorted(BASELINE))
def test_final_configuration_unchanged(key):
    scenario, controller, solver, mode = key.split("/")
    setup, log = run(ROBOT.get(scenario, "arm"), scenario, controller, "daqp" if solver == "none" else solver, mode,
                 on_failure="stop")
    expected = BASELINE[key]
    assert len(log.t) == expected["steps"]
    if key.startswith("hexapod-stroke-limits/pinv/"):
        return
    reference = BASELINE[f"{scenario}/{controller}/{'daqp' if controller == 'qp' else solver}/{mode}"]
    np.testing.assert_allclose(log.q[-1], reference["q_final"], rtol=0, atol=rounding_tolerance(setup, log))
