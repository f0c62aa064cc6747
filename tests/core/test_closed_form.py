"""The closed-form fast path returns the solver's answer: checked step by step against
the solver on the bundled scenarios, and on random equality-constrained QPs."""

from __future__ import annotations

import numpy as np
import pytest

from qpik.controllers.closed_form import ClosedFormStep
from qpik.scenario import build_scenario
from qpik.solvers import make_backend


@pytest.mark.parametrize("scenario", ["seed-redundant", "joint-limits", "unreachable", "hexapod-position-only"])
def test_fast_path_equals_the_solver_step_by_step(scenario):
    fast_setup, slow_setup = build_scenario(scenario), build_scenario(scenario)
    fast = fast_setup.controller("qp", "daqp")
    slow = slow_setup.controller("qp", "daqp", fast_path=False)
    steps = int(round(fast_setup.duration / fast_setup.dt))
    worst = 0.0
    for k in range(steps):
        t = k * fast_setup.dt
        for setup in (fast_setup, slow_setup):
            setup.reference.apply(t)
        slow_setup.robot.set_q(fast_setup.robot.q)  # same state for both
        a, b = fast.compute_velocity(), slow.compute_velocity()
        worst = max(worst, float(np.max(np.abs(a - b)) / (1.0 + np.max(np.abs(b)))))
        fast_setup.robot.integrate(a, fast_setup.dt)
    assert worst <= 1e-12
    assert slow.solver_calls == steps
    if scenario in ("joint-limits", "unreachable"):
        assert 0 < fast.solver_calls < steps  # limits bind on some steps only


@pytest.mark.parametrize("hessian", ["uniform", "diagonal", "dense", "per-call"])
@pytest.mark.parametrize("meq", [0, 1, 2, 4, 7])
def test_kkt_solution_on_random_problems(hessian, meq):
    rng = np.random.default_rng(meq)
    nv = 7
    for _ in range(20):
        if hessian == "uniform":
            H = np.eye(nv) * rng.uniform(0.1, 3.0)
        elif hessian == "diagonal":
            H = np.diag(rng.uniform(0.1, 3.0, nv))
        else:
            M = rng.normal(size=(nv, nv))
            H = M @ M.T + 0.1 * np.eye(nv)
        c = rng.normal(size=nv)
        A = rng.normal(size=(meq, nv))
        b = rng.normal(size=meq)
        step = ClosedFormStep(None if hessian == "per-call" else H, meq)
        x = step.solve(H, np.vstack([A, c]), b)
        backend = make_backend("daqp", nv, meq)
        backend.A[:], backend.b[:] = A, b
        np.testing.assert_allclose(x, backend.solve(H, c), rtol=1e-10, atol=1e-10)


def test_dependent_hard_rows_are_left_to_the_solver():
    H = np.eye(3)
    A = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]])  # the same row twice
    for meq_rows in (A, np.vstack([A, [[0.0, 0.0, 1.0]]])):
        Ac = np.vstack([meq_rows, np.zeros(3)])
        assert ClosedFormStep(H, len(meq_rows)).solve(H, Ac, np.ones(len(meq_rows))) is None
