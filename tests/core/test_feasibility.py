"""has_feasible_point (the phase-1 problem DAQP solves) decides as an independent LP
(SciPy's HiGHS) on random constraint sets: independent and dependent hard rows,
consistent or not, boxes and general rows that admit a point or exclude each other."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from qpik.controllers.fallbacks import has_feasible_point
from qpik.solvers import available_solvers, make_backend


def _lp_feasible(backend) -> bool:
    finite = np.isfinite(backend.h)
    result = linprog(np.zeros(backend.nv), A_ub=backend.G[finite] if finite.any() else None,
                     b_ub=backend.h[finite] if finite.any() else None,
                     A_eq=backend.A if backend.meq else None, b_eq=backend.b if backend.meq else None,
                     bounds=np.column_stack([backend.lb, backend.ub]), method="highs")
    assert result.status in (0, 2), result.message
    return result.status == 0


def _random_problem(rng, solver: str):
    nv = int(rng.integers(2, 9))
    meq = int(rng.integers(0, nv + 3))  # more rows than dofs: dependent rows
    mineq = int(rng.integers(0, 6))
    backend = make_backend(solver, nv, meq, mineq)
    x0 = rng.normal(size=nv)
    A = rng.normal(size=(meq, nv))
    independent = min(meq, nv - 1)
    if meq > independent:  # the extra rows combine the first ones
        A[independent:] = rng.normal(size=(meq - independent, independent)) @ A[:independent]
    b = A @ x0
    if meq and rng.random() < 0.3:
        b[-1] += rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 1.0)  # inconsistent if dependent
    backend.A[:], backend.b[:] = A, b
    backend.G[:] = rng.normal(size=(mineq, nv))
    backend.h[:] = backend.G @ x0 + rng.uniform(-1.0, 1.0, mineq)
    if mineq:
        backend.h[rng.random(mineq) < 0.2] = np.inf  # absent rows
    width = rng.uniform(0.05, 2.0, nv)
    center = x0 + rng.normal(scale=1.5, size=nv)
    backend.lb[:], backend.ub[:] = center - width, center + width
    backend.lb[rng.random(nv) < 0.2] = -np.inf
    return backend


@pytest.mark.parametrize("solver", sorted({"daqp", "osqp"} & set(available_solvers())))
def test_the_phase_one_problem_decides_as_an_lp(solver):
    rng = np.random.default_rng(7)
    decisions = {True: 0, False: 0}
    for case in range(400):
        backend = _random_problem(rng, solver)
        expected = _lp_feasible(backend)
        assert has_feasible_point(backend) == expected, case
        decisions[expected] += 1
    assert min(decisions.values()) >= 50, decisions  # both kinds of problem, many of each


def test_dependent_consistent_hard_rows_are_feasible_and_inconsistent_ones_not():
    """Two copies of one row (two hard tasks on one frame): DAQP alone refuses such
    equalities as an overdetermined initial active set, whatever b."""
    backend = make_backend("daqp", 3, 3, 0)
    backend.A[:] = [[1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 1.0]]
    backend.lb[:], backend.ub[:] = -1.0, 1.0
    backend.b[:] = [1.0, 2.0, 0.5]
    assert has_feasible_point(backend)
    backend.b[1] = 2.1
    assert not has_feasible_point(backend)
    backend.b[1] = 2.0 + 1e-9  # within the tolerance an LP has too
    assert has_feasible_point(backend)
    backend.b[:] = [3.0, 6.0, 0.5]  # consistent, but outside the box
    assert not has_feasible_point(backend)
