"""Every back-end on the same random QPs with equalities, general inequalities and boxes,
against an independent reference: the KKT conditions solved on the active set."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from qpik.errors import InfeasibleProblem, SolverError, UnknownName
from qpik.solvers import available_solvers, make_backend
from qpik.solvers.base import equalities_met

SOLVERS = [s for s in ("daqp", "osqp", "proxqp", "quadprog") if s in available_solvers()]


def random_qp(rng, nv=6, meq=2, mineq=3):
    M = rng.normal(size=(nv, nv))
    H = M @ M.T + 0.5 * np.eye(nv)
    c = rng.normal(size=nv) * 3.0
    A = rng.normal(size=(meq, nv))
    x0 = rng.uniform(-0.5, 0.5, size=nv)  # a strictly feasible point
    b = A @ x0
    G = rng.normal(size=(mineq, nv))
    h = G @ x0 + rng.uniform(0.05, 0.5, size=mineq)
    lb = x0 - rng.uniform(0.1, 1.0, size=nv)
    ub = x0 + rng.uniform(0.1, 1.0, size=nv)
    return H, c, A, b, G, h, lb, ub


def kkt_solution(H, c, A, b, G, h, lb, ub, x, tol=1e-6):
    """Re-solve the equality-constrained QP on the constraints active at x (closed form)."""
    nv = len(c)
    rows, rhs = [A], [b]
    active_g = G @ x >= h - tol
    rows.append(G[active_g]); rhs.append(h[active_g])
    eye = np.eye(nv)
    at_lb, at_ub = x <= lb + tol, x >= ub - tol
    rows += [eye[at_lb], eye[at_ub]]; rhs += [lb[at_lb], ub[at_ub]]
    C, d = np.vstack(rows), np.concatenate(rhs)
    m = len(d)
    K = np.block([[H, C.T], [C, np.zeros((m, m))]])
    sol = np.linalg.lstsq(K, np.concatenate([-c, d]), rcond=None)[0]
    multipliers = sol[nv:]
    # Inequality multipliers (G rows, upper bounds) must be >= 0 with this sign convention;
    # lower bounds enter as -x <= -lb, i.e. their multiplier in C x = d is <= 0.
    n_eq, n_g, n_lb = len(b), int(active_g.sum()), int(at_lb.sum())
    g_mult = multipliers[n_eq:n_eq + n_g]
    lb_mult = multipliers[n_eq + n_g:n_eq + n_g + n_lb]
    ub_mult = multipliers[n_eq + n_g + n_lb:]
    return sol[:nv], g_mult, lb_mult, ub_mult


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("native", [True, False])
def test_general_inequalities_and_boxes_match_the_kkt_reference(solver, native):
    rng = np.random.default_rng(7)
    binding = 0
    for _ in range(30):
        H, c, A, b, G, h, lb, ub = random_qp(rng)
        backend = make_backend(solver, 6, 2, 3, native=native)
        backend.A[:] = A; backend.b[:] = b; backend.G[:] = G; backend.h[:] = h
        backend.lb[:] = lb; backend.ub[:] = ub
        x = backend.solve(H, c)
        assert np.all(x >= lb) and np.all(x <= ub)
        np.testing.assert_allclose(A @ x, b, atol=1e-7)
        assert np.all(G @ x <= h + 1e-7)
        reference, g_mult, lb_mult, ub_mult = kkt_solution(H, c, A, b, G, h, lb, ub, x)
        np.testing.assert_allclose(x, reference, atol=1e-6)
        assert np.all(g_mult >= -1e-6) and np.all(ub_mult >= -1e-6) and np.all(lb_mult <= 1e-6)
        binding += int(len(g_mult) > 0)
    assert binding >= 5  # the random problems do exercise the general rows


@pytest.mark.parametrize("solver", SOLVERS)
def test_empty_box_is_infeasible_naming_the_variable(solver):
    backend = make_backend(solver, 3, 0)
    backend.lb[:] = [-1.0, 0.5, -1.0]
    backend.ub[:] = [1.0, 0.2, 1.0]
    with pytest.raises(InfeasibleProblem, match="variable 1") as info:
        backend.solve(np.eye(3), np.zeros(3))
    assert info.value.variable == 1


@pytest.mark.parametrize("solver", SOLVERS)
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_data_is_a_solver_error(solver, bad):
    backend = make_backend(solver, 3, 1)
    backend.A[:] = [[1.0, 0.0, 0.0]]
    c = np.array([0.0, bad, 0.0])
    with pytest.raises(SolverError, match="NaN or inf"):
        backend.solve(np.eye(3), c)


def test_osqp_never_returns_a_stale_answer_after_a_rejected_update():
    backend = make_backend("osqp", 2, 0)
    backend.lb[:] = -1.0
    backend.ub[:] = 1.0
    first = backend.solve(np.eye(2), np.array([0.5, -0.5]))
    np.testing.assert_allclose(first, [-0.5, 0.5], atol=1e-7)
    backend.lb[:] = [2.0, -1.0]  # l > u on the first variable: OSQP rejects the update
    with pytest.raises(SolverError, match="rejected"):
        backend._solve(np.eye(2), np.array([0.4, -0.4]), True)


def test_unknown_solver_lists_the_installed_ones():
    with pytest.raises(UnknownName, match="daqp"):
        make_backend("no_such_solver", 2, 0)


@pytest.mark.parametrize("solver", [s for s in ("daqp", "quadprog") if s in available_solvers()])
def test_an_answer_that_lost_the_hard_rows_last_digits_is_moved_back_onto_them(solver):
    """An ill-conditioned step (any-robot fuzz case 560: a hard CoM task beside a connect
    equality, 25 dofs) came back from quadprog, then daqp, missing A x = b by 8.4e-6: above
    the exact solvers' 1e-9 (1 + |b|), a SolverError although an LP finds the step
    feasible. The check now corrects the free dofs by least squares (a dof at
    its bound stays there) and keeps the point only if it then meets the rows inside the
    box. A point that cannot be corrected (every dof at a bound) is still refused."""
    rng = np.random.default_rng(3)
    nv, meq = 6, 2
    backend = make_backend(solver, nv, meq)
    backend.A[:] = rng.normal(size=(meq, nv))
    backend.lb[:], backend.ub[:] = -1.0, 1.0
    x = rng.uniform(-0.5, 0.5, nv)
    x[0] = backend.ub[0]  # one dof at its bound
    backend.b[:] = backend.A @ x
    lost = x + np.r_[0.0, rng.normal(0.0, 1e-8, nv - 1)]  # the rows' last digits lost
    answer = backend._check_result(lost.copy())
    assert np.abs(backend.A @ answer - backend.b).max() <= 1e-12
    assert np.all(answer >= backend.lb) and np.all(answer <= backend.ub) and answer[0] == backend.ub[0]
    assert np.abs(answer - x).max() < 1e-7  # a correction of the lost digits' size
    pinned = np.where(rng.random(nv) < 0.5, backend.lb, backend.ub)
    with pytest.raises(SolverError, match="misses the equality"):
        backend._check_result(pinned)


@pytest.mark.parametrize("solver", SOLVERS)
def test_an_answer_too_large_for_its_hard_rows_to_be_checked_is_refused(solver):
    """A point 3e7 along the null space of rows with entries ~400 (|b| ~ 400): the
    rounding of its entries leaves ~2.5e-6 in A x, 6 times the exact solvers' 1e-9
    (1 + |b|) (3e10 for the iterative solvers' 1e-6), so whether its residual passes is
    largely the rounding's (any-robot case 8160: passed in one run, failed in another).
    It is refused though A x - b evaluates to exactly 0 here; the same rows at a size
    they can be checked at pass."""
    rng = np.random.default_rng(5)
    nv, meq = 8, 2
    backend = make_backend(solver, nv, meq)
    A = backend.A
    A[:] = rng.uniform(-400.0, 400.0, (meq, nv))
    null = np.linalg.svd(A)[2][meq:].T
    for size, checkable in ((3e7 * backend.equality_tolerance / 1e-9, False), (30.0, True)):
        x = rng.normal(size=nv) + null @ rng.normal(size=nv - meq) * size
        backend.b[:] = A.dot(x)  # as the check evaluates it: a residual of 0
        if checkable:
            assert np.array_equal(backend._check_result(x.copy()), x)
        else:
            with pytest.raises(SolverError, match="too large to check"):
                backend._check_result(x.copy())


@pytest.mark.parametrize("seed, pull", [(0, 3e7), (1, 3e7), (2, 1e7), (3, 3e11)])
def test_the_capped_ladder_stops_where_its_answers_hard_rows_can_be_checked(seed, pull):
    """Any-robot case 8160's level, cut down: two hard rows of entries ~400, half the dofs
    boxed with curvature 1e7, half free with curvature 1 and a soft pull ``pull``. A
    solver's answer at a cap 1e9 or 1e6 times H's scale lies ~1e7 along the rows' null
    space, too large to check them at, so the guard's ladder goes on (1e3, 1, 1e-3, no
    cost): its answer is the minimiser (H with the retry's damping) at the first cap where
    that is small enough (u ‖A∘x‖ <= 1e-9 (1 + |b|)), the same for b moved by a rounding.
    Before, an answer 3 to 6 times past that came back where the check happened to pass
    (case 8160's two runs stopped at different caps, 1e3 and 1, 1.0 apart), and the
    ladder ended at 1."""
    from qpik.controllers.fallbacks import GuardedSolve
    from qpik.problem.cost import COST_SCALE_CAP, tame
    from qpik.solvers.base import EXACT_EQUALITY_TOLERANCE
    from qpik.solvers.nullspace import NullSpaceBackend

    rng = np.random.default_rng(seed)
    nv, meq, half = 10, 2, 5
    A = rng.uniform(-400.0, 400.0, (meq, nv))
    H = np.diag(np.r_[np.full(half, 1e7), np.ones(nv - half)])
    c = np.r_[rng.normal(size=half) * 1e11, rng.normal(size=nv - half) * pull]
    b = rng.normal(size=meq) * 100.0
    lb, ub = np.full(nv, -np.inf), np.full(nv, np.inf)
    lb[:half], ub[:half] = -1.0, 1.0

    def checkable(x):
        rounding = 0.5 * np.finfo(float).eps * np.linalg.norm(A * x)
        return rounding <= EXACT_EQUALITY_TOLERANCE * (1 + np.linalg.norm(b))

    damped = H + 1e-9 * np.trace(H) / nv * np.eye(nv)  # the guard's retry's damping
    minimisers = []
    for cap in (COST_SCALE_CAP, 1e6, 1e3, 1.0, 1e-3, 0.0):  # the ladder docs/controllers.md states
        reference = NullSpaceBackend(nv, meq, 0)
        reference.A[:], reference.b[:], reference.lb[:], reference.ub[:] = A, b, lb, ub
        reference.equality_tolerance = 1.0  # every cap's minimiser, checkable or not
        minimisers.append(reference.solve(damped, tame(c, float(damped.diagonal().max()), cap)))
    assert not checkable(minimisers[0])
    expected = next(x for x in minimisers if checkable(x))
    for moved in (0.0, 1e-15, -2e-15):
        backend = make_backend("daqp", nv, meq)
        backend.A[:], backend.b[:], backend.lb[:], backend.ub[:] = A, b * (1.0 + moved), lb, ub
        x = GuardedSolve(backend, "daqp").solve(H, c)
        assert checkable(x) and np.abs(A @ x - b).max() <= 1e-9 * (1 + np.linalg.norm(b))
        assert np.linalg.norm(x - expected) <= 1e-8 * np.linalg.norm(expected)


def test_a_far_equality_row_does_not_excuse_a_near_rows_miss():
    """Every solver's answer is held to each hard row at its own scale as well as to the
    norm-wise 1e-9 (1 + |b|): any-robot case 4966, a hierarchy level's rows above it, a
    position 6e7 away beside pose rows of about 9, which DAQP met 6e-4 off."""
    A, b = np.eye(2), np.array([6e7, 9.0])
    assert not equalities_met(A, b + np.array([0.0, 6e-4]), b, 1e-9)  # norm-wise alone: within 0.06
    assert equalities_met(A, b + np.array([1e-3, 1e-9]), b, 1e-9)  # each row within 1e-9 (1 + |b_i| + |A_i||x|)


def _stationarity(step, x):
    """How far x is from a KKT point of min ½‖R₁x − r₁‖² + ½xᵀDx + c₀ᵀx under the step's
    rows and box: the gradient's least-squares remainder after multipliers of the hard rows
    (free) and of the bounds and row x is on (with their signs; BVLS), relative to the size
    of the gradient's terms."""
    from scipy.optimize import lsq_linear

    R1, r1, D, c0, A, lb, ub, G, h = (step[k] for k in ("R1", "r1", "D", "c0", "A", "lb", "ub", "G", "h"))
    gradient = R1.T @ (R1 @ x - r1) + D * x + c0
    terms = np.abs(R1.T) @ (np.abs(R1) @ np.abs(x) + np.abs(r1)) + np.abs(D * x) + np.abs(c0)
    near = 1e-9  # a bound DAQP holds is met exactly; one it does not is far from this
    at_lower = np.isfinite(lb) & (x - lb <= near * (1 + np.abs(lb)))
    at_upper = np.isfinite(ub) & (ub - x <= near * (1 + np.abs(ub)))
    at_row = np.isfinite(h) & (h - G @ x <= near * (1 + np.abs(h)))
    eye = np.eye(len(x))
    columns = np.hstack([A.T, -eye[:, at_lower], eye[:, at_upper], G[at_row].T])
    columns /= np.linalg.norm(columns, axis=0)
    free = np.zeros(columns.shape[1])
    free[: len(A)] = -np.inf
    fit = lsq_linear(columns, -gradient, bounds=(free, np.inf), method="bvls")
    return np.linalg.norm(columns @ fit.x + gradient) / np.linalg.norm(terms)


def test_a_step_whose_hessian_is_indefinite_in_floats_is_solved_in_its_row_form():
    """Any-robot case 3870, step 3, a robot 1e6 m out: 8 soft rows with entries up to 1e5
    on 46 dofs that ε = 1e-12 alone weighs otherwise, 6 hard rows, a box and a collision
    row. H = D + R₁ᵀR₁ formed in floats has eigenvalues down to −3e-6 (its rounding, ε‖H‖,
    is 2e-6): DAQP called the step unbounded, and the retry with 1e-9 of H's scale as
    damping answered another QP. The guard's retry now solves the same QP in its row form
    (a diagonal Hessian): its answer is a KKT point of the step to a few roundings of the
    gradient's terms (backward stable: nv·ε is 1e-14; 1e-12 allowed) and meets the hard
    rows, where the damped QP's answer is neither stationary nor as cheap."""
    from qpik.controllers.fallbacks import GuardedSolve

    step = dict(np.load(Path(__file__).resolve().parents[1] / "data" / "row_form_step.npz"))
    R1, r1, D, c0, A, b = (step[k] for k in ("R1", "r1", "D", "c0", "A", "b"))
    nv = len(D)
    backend = make_backend("daqp", nv, len(A), len(step["h"]))
    for name in ("A", "b", "G", "h", "lb", "ub"):
        getattr(backend, name)[:] = step[name]
    x = GuardedSolve(backend, "daqp")._row_form(R1, r1, D, c0)
    assert x is not None and _stationarity(step, x) <= 1e-12
    assert equalities_met(A, x, b, 1e-9) and np.all((step["lb"] <= x) & (x <= step["ub"]))
    H = R1.T @ R1 + np.diag(D)
    damped = backend.solve(H + 1e-9 * np.trace(H) / nv * np.eye(nv), c0 - R1.T @ r1)
    assert _stationarity(step, damped) > 1e-12

    def cost(v):
        return 0.5 * np.sum((R1 @ v - r1) ** 2) + 0.5 * v @ (D * v) + c0 @ v

    assert cost(x) < cost(damped)


def test_a_step_the_solver_sits_out_is_answered_by_a_counted_retry():
    """After a failure the solver sits out its next steps: the guard answers them by the
    row form where it has the rows, else by the damped QP (another QP than the step's),
    and counts each in ``fallbacks``, the number a controller reports."""
    from qpik.controllers.fallbacks import GuardedSolve

    step = dict(np.load(Path(__file__).resolve().parents[1] / "data" / "row_form_step.npz"))
    R1, r1, D, c0 = (step[k] for k in ("R1", "r1", "D", "c0"))
    H, c = R1.T @ R1 + np.diag(D), c0 - R1.T @ r1
    for rows in (lambda: (R1, r1, D, c0), None):
        backend = make_backend("daqp", len(D), len(step["A"]), len(step["h"]))
        for name in ("A", "b", "G", "h", "lb", "ub"):
            getattr(backend, name)[:] = step[name]
        guard = GuardedSolve(backend, "daqp")
        guard._pause.failed()
        x = guard.solve(H, c, rows=rows)
        assert guard.fallbacks == 1
        assert (_stationarity(step, x) <= 1e-12) == (rows is not None)
