"""Hard rows whose scales the dual solvers cannot resolve (a robot stretched a million
metres: a row holds entries of 1e6 beside 1e-2, and the dof carrying the large entry is
at its bound) are solved exactly in the rows' null space, and their feasibility decided
as an LP decides it.

The 4-dof problem is the level 0 of any-robot fuzz case 661 (hierarchy, two hard
position tasks), cut to the dofs its rows touch: every solver called it infeasible.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.optimize import linprog

from qpik.controllers.fallbacks import GuardedSolve, has_feasible_point
from qpik.errors import InfeasibleProblem, SolverError
from qpik.solvers import available_solvers, make_backend
from qpik.solvers.nullspace import NullSpaceBackend

A = np.array([[1996.856, 0.0, 0.0, -0.6691246],
              [-896561.3, 0.3279339, 0.03178876, 0.0]])
B = np.array([2.333050e6, 3.541269e9])
LOWER = np.array([-0.3585849, -4.930058e8, -np.inf, -np.inf])
UPPER = np.array([1350.425, 1.477564e-6, np.inf, np.inf])


def _stretched(solver: str):
    backend = make_backend(solver, 4, 2, 0)
    backend.A[:], backend.b[:], backend.lb[:], backend.ub[:] = A, B, LOWER, UPPER
    return backend


def _minimum_norm_by_active_sets() -> np.ndarray:
    """min ½‖x‖² under the rows and the box, by trying every choice of bounds for the two
    bounded dofs (each a least-squares solve of the rows on the free dofs) and keeping
    the smallest point that meets everything: the QP's minimiser is one of them."""
    best = None
    for choice in itertools.product((None, "lower", "upper"), repeat=2):
        x = np.zeros(4)
        fixed = [j for j, side in enumerate(choice) if side]
        for j in fixed:
            x[j] = LOWER[j] if choice[j] == "lower" else UPPER[j]
        free = [j for j in range(4) if j not in fixed]
        x[free] = np.linalg.lstsq(A[:, free], B - A[:, fixed] @ x[fixed], rcond=None)[0]
        meets = np.all(x >= LOWER) and np.all(x <= UPPER) and \
            np.linalg.norm(A @ x - B) <= 1e-9 * (1.0 + np.linalg.norm(B))
        if meets and (best is None or x @ x < best @ best):
            best = x
    return best


@pytest.mark.parametrize("solver", [s for s in ("daqp", "quadprog", "osqp", "proxqp") if s in available_solvers()])
def test_a_hard_row_carried_by_a_dof_at_its_bound_is_solved_by_every_solver(solver):
    expected = _minimum_norm_by_active_sets()
    assert expected[0] == LOWER[0] and expected[1] == UPPER[1] and abs(expected[2]) > 1e11  # the hard case
    x = GuardedSolve(_stretched(solver), solver).solve(np.eye(4), np.zeros(4))
    # Judged as the active set it must be, not entry by entry: x[1] (1.5e-6) sits beside
    # entries of 1e11 and is rounding-level in this problem (it moved 4e-10 under another
    # OpenBLAS kernel). The rows met and the box kept, as every answer promises:
    assert np.linalg.norm(A @ x - B) <= 1e-9 * (1.0 + np.linalg.norm(B))
    assert np.all(x >= LOWER) and np.all(x <= UPPER)
    # the two bounded dofs at the bounds the exact minimiser holds, to the solvers' bound
    # tolerance 1e-9 (1 + |bound|) ...
    for j, bound in ((0, LOWER[0]), (1, UPPER[1])):
        assert abs(x[j] - bound) <= 1e-9 * (1.0 + abs(bound))
    # ... which leaves the free dofs fixed by the rows (A[:, 2:] is invertible): the point
    # equals the minimiser norm-wise to rounding of the rows amplified by their
    # conditioning, 10 κ(A) ε ‖x*‖ (κ(A) = 1.3e6: about 3e-9 relative).
    tolerance = 10.0 * np.linalg.cond(A) * np.finfo(float).eps * np.linalg.norm(expected)
    assert np.linalg.norm(x - expected) <= tolerance


def test_its_feasibility_is_decided_as_an_lp_decides_it():
    lp = linprog(np.zeros(4), A_eq=A, b_eq=B, bounds=np.column_stack([LOWER, UPPER]), method="highs")
    assert lp.status == 0
    assert has_feasible_point(_stretched("daqp"))


def _random_problem(rng, nv: int, meq: int, mineq: int, dependent: bool):
    x0 = rng.normal(size=nv)
    A = rng.normal(size=(meq, nv))
    if dependent and meq > 1:
        A[-1] = 2.0 * A[0] - A[1]  # consistent: b comes from x0
    G = rng.normal(size=(mineq, nv))
    lower, upper = x0 - rng.uniform(0.0, 0.5, nv), x0 + rng.uniform(0.0, 0.5, nv)
    lower[rng.random(nv) < 0.3] = -np.inf
    h = G @ x0 + rng.uniform(0.0, 0.5, mineq)
    M = rng.normal(size=(nv, nv))
    return M @ M.T + 0.1 * np.eye(nv), 3.0 * rng.normal(size=nv), A, A @ x0, G, h, lower, upper


@pytest.mark.parametrize("dependent", [False, True])
def test_the_null_space_solve_is_the_minimiser_on_ordinary_problems(dependent):
    """Strictly convex problems with binding bounds and rows (dependent hard rows
    included, which DAQP refuses as a starting active set): the KKT conditions hold at
    the null-space answer, with multipliers from a least-squares fit on its active set."""
    rng = np.random.default_rng(3)
    for case in range(40):
        nv, meq, mineq = int(rng.integers(3, 9)), int(rng.integers(1, 4)), int(rng.integers(0, 4))
        H, c, A_, b, G, h, lower, upper = _random_problem(rng, nv, meq, mineq, dependent)
        backend = NullSpaceBackend(nv, meq, mineq)
        backend.A[:], backend.b[:], backend.G[:], backend.h[:] = A_, b, G, h
        backend.lb[:], backend.ub[:] = lower, upper
        x = backend.solve(H, c)
        assert np.linalg.norm(A_ @ x - b) <= 1e-9 * (1.0 + np.linalg.norm(b)), case
        assert np.all(x >= lower) and np.all(x <= upper) and np.all(G @ x <= h + 1e-9), case
        at_lower, at_upper = np.abs(x - lower) <= 1e-9, np.abs(x - upper) <= 1e-9
        active_rows = np.abs(G @ x - h) <= 1e-9
        normals = np.vstack([A_, -np.eye(nv)[at_lower], np.eye(nv)[at_upper], G[active_rows]])
        multipliers = np.linalg.lstsq(normals.T, -(H @ x + c), rcond=None)[0]
        stationarity = H @ x + c + normals.T @ multipliers
        assert np.abs(stationarity).max() <= 1e-8 * (1.0 + np.abs(c).max()), case
        assert np.all(multipliers[meq:] >= -1e-8), case  # inequality multipliers: signs of a minimum


def test_hard_rows_that_fix_a_dof_outside_its_box_are_infeasible():
    backend = NullSpaceBackend(2, 2, 0)
    backend.A[:], backend.b[:] = np.eye(2), [0.5, 3.0]
    backend.lb[:], backend.ub[:] = -1.0, 1.0
    with pytest.raises(InfeasibleProblem):
        backend.solve(np.eye(2), np.zeros(2))


def test_dependent_hard_rows_that_disagree_beyond_the_promise_are_named_as_the_cause():
    """Two hard tasks on the same motion whose targets disagree by 1e-8 relative: phase 1
    (1e-7) finds the set feasible, no solver can meet the rows to 1e-9, and the error
    says so rather than blaming the cost."""
    backend = make_backend("daqp", 2, 2, 0)
    backend.A[:] = [[1.0, 1.0], [2.0, 2.0]]
    backend.b[:] = [1e9, 2e9 * (1.0 + 1e-8)]
    with pytest.raises(SolverError, match=r"hard rows alone can be met to [0-9.e-]+ \(relative\) at best.*disagree"):
        GuardedSolve(backend, "daqp").solve(np.eye(2), np.zeros(2))
