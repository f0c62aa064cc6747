"""The engine's closed form (qpik.problem.closed_form) against independent references: the
equality-constrained minimiser (DampedLeastSquares, with and without held dofs) against its KKT
system solved by NumPy on random problems over N worlds; dependent rows refused; the
bounds held (HeldBounds) against DAQP called directly on random boxed QPs; rows_met and
inside, their one-world float paths against their N-world paths; the damped
least-squares step against its KKT system; a capped cost left to the solver; and the
bundled scenarios, whose every step is the minimiser of its QP solved independently."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from qpik import DampingTask, PostureTask, QPController, Robot
from qpik.problem import closed_form
from qpik.problem.closed_form import DampedLeastSquares, HeldBounds, inside, rows_met
from qpik.scenario import build_scenario

_spec = importlib.util.spec_from_file_location("references", Path(__file__).parents[1] / "engine" / "references.py")
references = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(references)

EPS = np.finfo(float).eps
NV = 7


def _costs(rng, n: int, kind: str):
    """D (n, NV) and soft rows R₁ (n, m, NV) with r₁ (n, m): H = D + R₁ᵀR₁ is a uniform
    diagonal, a diagonal, or dense (three soft rows)."""
    if kind == "uniform":
        D = np.ones((n, NV)) * rng.uniform(0.1, 3.0, (n, 1))
    else:
        D = rng.uniform(0.1, 3.0, (n, NV))
    m = 3 if kind == "dense" else 0
    return D, rng.normal(size=(n, m, NV)), rng.normal(size=(n, m))


def _dense(D, R1, r1, c):
    """H = D + R₁ᵀR₁ and the QP's c − R₁ᵀr₁ of one world."""
    return np.diag(D) + R1.T @ R1, c - R1.T @ r1


def _kkt(H, c, A, b, fixed=None, values=None):
    """x and y of min ½xᵀHx + cᵀx s.t. Ax = b (and x_i = v_i on the held dofs) from the KKT
    system [[H, −Aᵀ, −Eᵀ], [A, 0, 0], [E, 0, 0]] [x; y; μ] = [−c; b; v], NumPy's LU, and
    the system's condition number."""
    held = np.flatnonzero(fixed) if fixed is not None else np.zeros(0, dtype=int)
    E = np.eye(NV)[held]
    rows = np.vstack([A, E])
    m = len(rows)
    kkt = np.block([[H, -rows.T], [rows, np.zeros((m, m))]])
    solution = np.linalg.solve(kkt, np.concatenate([-c, b, values[held] if len(held) else np.zeros(0)]))
    return solution[:NV], solution[NV:NV + len(A)], np.linalg.cond(kkt)


@pytest.mark.parametrize("n", [1, 5])
@pytest.mark.parametrize("hessian", ["uniform", "diagonal", "dense"])
@pytest.mark.parametrize("meq", [0, 1, 2, 4, 7])
def test_the_equality_minimiser_is_the_kkt_solution_in_every_world(n, hessian, meq):
    """Random strictly convex problems (7 dofs, meq rows; meq = 7: x fixed by the rows):
    x and the rows' multipliers z₂ (where a cost is minimised: not when 7 hard rows alone
    fix x) of every world against the KKT system (a backward-stable solve of each: they
    differ by ~ε κ(KKT), 1e3 ε κ allowed), the rows met."""
    rng = np.random.default_rng(10 * meq + n)
    for _ in range(10):
        D, R1, r1 = _costs(rng, n, hessian)
        c, A, b = rng.normal(size=(n, NV)), rng.normal(size=(n, meq, NV)), rng.normal(size=(n, meq))
        m = R1.shape[1]
        x, z, ok = DampedLeastSquares(n, NV, m, meq).solve(1.0 / D, np.concatenate([R1, A], 1),
                                                            np.concatenate([r1, b], 1), c)
        assert np.all(ok)
        for w in range(n):
            H, c_full = _dense(D[w], R1[w], r1[w], c[w])
            expected_x, expected_y, condition = _kkt(H, c_full, A[w], b[w])
            tolerance = 1e3 * EPS * condition
            assert np.linalg.norm(x[w] - expected_x) <= tolerance * (1.0 + np.linalg.norm(expected_x))
            if meq and z is not None:  # (None where the rows alone fix x: nothing minimised)
                assert np.linalg.norm(z[w, m:] - expected_y) <= tolerance * (1.0 + np.linalg.norm(expected_y))
                assert np.linalg.norm(A[w] @ x[w] - b[w]) <= 1e-10 * (1.0 + np.linalg.norm(b[w]))


@pytest.mark.parametrize("n", [1, 4])
@pytest.mark.parametrize("hessian", ["diagonal", "dense"])
@pytest.mark.parametrize("meq", [0, 2, 4])
def test_held_dofs_are_their_values_and_the_rest_the_kkt_solution(n, hessian, meq):
    """Some dofs held at given values (a different set in every world): x equals the values
    there exactly and the KKT solution of the problem with those equalities added."""
    rng = np.random.default_rng(100 + 10 * meq + n)
    for _ in range(10):
        D, R1, r1 = _costs(rng, n, hessian)
        c, A, b = rng.normal(size=(n, NV)), rng.normal(size=(n, meq, NV)), rng.normal(size=(n, meq))
        fixed = np.zeros((n, NV), dtype=bool)
        for w in range(n):
            fixed[w, rng.permutation(NV)[:int(rng.integers(1, NV - meq))]] = True
        values = np.where(fixed, rng.normal(size=(n, NV)), 0.0)
        x, _, ok = DampedLeastSquares(n, NV, R1.shape[1], meq).solve(
            1.0 / D, np.concatenate([R1, A], 1), np.concatenate([r1, b], 1), c, fixed, values)
        assert np.all(ok)
        np.testing.assert_array_equal(x[fixed], values[fixed])
        for w in range(n):
            H, c_full = _dense(D[w], R1[w], r1[w], c[w])
            expected, _, condition = _kkt(H, c_full, A[w], b[w], fixed[w], values[w])
            assert np.linalg.norm(x[w] - expected) <= 1e3 * EPS * condition * (1.0 + np.linalg.norm(expected))


@pytest.mark.parametrize("n", [1, 3])
def test_dependent_or_zero_rows_are_refused_in_their_world_alone(n):
    """The same row twice, and a row of zeros: A D⁻¹ Aᵀ is singular, the world is refused
    (left to the solver); the other worlds are solved."""
    A = np.tile(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0]]), (n, 1, 1))
    for bad in (np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]]), np.array([[1.0, 2.0, 0.0], [0.0, 0.0, 0.0]])):
        A[-1] = bad
        _, _, ok = DampedLeastSquares(n, 3, 0, 2).solve(np.ones((n, 3)), A, np.ones((n, 2)), np.zeros((n, 3)))
        assert np.asarray(ok).tolist() == [True] * (n - 1) + [False]


def _qp_reference(H, c, A, b, lower, upper):
    """The minimiser of one world's boxed QP: DAQP called directly and made exact on its
    active set (references.LeastSquaresQP on R = Lᵀ, r = −L⁻¹c, H = LLᵀ)."""
    L = np.linalg.cholesky(H)
    return references.LeastSquaresQP(L.T, -np.linalg.solve(L, c), A, b, lower, upper).solve()


@pytest.mark.parametrize("hessian", ["diagonal", "dense"])
@pytest.mark.parametrize("meq", [0, 1, 3])
def test_held_bounds_give_the_qps_minimiser_or_nothing(hessian, meq):
    """Random strictly convex QPs in a tight box (4 worlds, 10 draws): held at the bounds
    active at the minimiser (remember), every world's closed form is the minimiser (1e-9);
    held at a wrong guess, a world's answer is the minimiser (after releasing and holding
    bounds) or it is left to the solver: never another point (the KKT check decides)."""
    rng = np.random.default_rng(10 + meq)
    n, held_right, repaired = 4, 0, 0
    box = np.tile(np.stack([np.full(NV, -0.5), np.full(NV, 0.5)]), (n, 1, 1))
    for _ in range(10):
        D, R1, r1 = _costs(rng, n, hessian)
        c, A, b = 3.0 * rng.normal(size=(n, NV)), rng.normal(size=(n, meq, NV)), 0.1 * rng.normal(size=(n, meq))
        dense = [_dense(D[w], R1[w], r1[w], c[w]) for w in range(n)]
        expected = np.array([_qp_reference(*dense[w], A[w], b[w], box[w, 0], box[w, 1]) for w in range(n)])
        cost = SimpleNamespace(dinv=1.0 / D, damping=D, R=np.concatenate([R1, A], 1), rhs=np.concatenate([r1, b], 1),
                               linear=c)
        held = HeldBounds(n, NV, R1.shape[1], meq)
        held.remember(np.arange(n), expected, box[:, 0], box[:, 1])
        held_right += int(held.lower.any(axis=1).sum() + held.upper.any(axis=1).sum())
        x, solved = held.solve(cost, box)
        assert np.all(solved)
        np.testing.assert_allclose(x, expected, rtol=0, atol=1e-9)
        for w in range(n):  # a guess: two dofs at their lower bound, one at its upper
            guess = rng.permutation(NV)[:3]
            held.lower[w], held.upper[w] = np.isin(np.arange(NV), guess[:2]), np.arange(NV) == guess[2]
        held.holding = True
        x, solved = held.solve(cost, box)
        np.testing.assert_allclose(x[solved], expected[solved], rtol=0, atol=1e-9)
        repaired += int(np.sum(solved))
    assert held_right >= 30  # the box binds in most worlds
    assert repaired >= 1  # and a wrong guess is repaired by the active-set steps at times


@pytest.mark.parametrize("n", [1, 4])
def test_rows_met_is_the_relative_residual_row_by_row_and_nan_fails(n):
    """|A_i x − b_i| <= tol (1 + |b_i|) on every row, per world; the screen for small
    misses and the row-by-row test answer alike; NaN fails."""
    rng = np.random.default_rng(n)
    for _ in range(50):
        b = rng.normal(size=(n, 3)) * rng.choice([0.0, 1.0, 1e3], size=(n, 3))
        miss = rng.normal(size=(n, 3)) * 10.0 ** rng.uniform(-13, -7, (n, 1))
        tolerance = 1e-10
        expected = (np.abs(miss) <= tolerance * (1.0 + np.abs(b))).all(axis=1)
        assert np.asarray(rows_met(b + miss, b.copy(), tolerance)).tolist() == expected.tolist()
    Ax = np.zeros((n, 3))
    Ax[-1, 0] = np.nan
    assert np.asarray(rows_met(Ax, np.zeros((n, 3)), 1e-10)).tolist() == [True] * (n - 1) + [False]


@pytest.mark.parametrize("n", [1, 3])
def test_inside_refuses_infinite_or_nan_answers_on_absent_bounds(n):
    """x = ±inf on a dof whose bound is absent (±inf), or NaN, is outside; a point on a
    bound is inside; the one-world float path answers as the N-world one, and no world's
    infinity raises a warning (the suite runs with warnings as errors). With rows, a world
    outside the box is outside, its rows unread."""
    inf = np.inf
    box = np.tile(np.array([[-inf, -1.0, 0.0], [inf, 1.0, 0.0]]), (n, 1, 1))
    G, h = np.tile([[1.0, 1.0, 1.0]], (n, 1, 1)), np.full((n, 1), 2.0)
    cases = {(inf, 0.0, 0.0): False, (-inf, 0.0, 0.0): False, (np.nan, 0.0, 0.0): False, (0.0, np.nan, 0.0): False,
             (1e300, 0.5, 0.0): True, (-1e300, -1.0, 0.0): True, (0.0, 1.0 + 1e-16, 0.0): True,
             (0.0, 1.0000000000000002, 0.0): False, (0.0, 0.0, 1e-300): False}
    for point, expected in cases.items():
        x = np.tile(point, (n, 1))
        assert np.asarray(inside(x, box)).tolist() == [expected] * n, point
        with_rows = expected and point[0] + point[1] <= 2.0
        assert np.asarray(inside(x, box, G, h)).tolist() == [with_rows] * n, point
    if n > 1:  # one world infinite among finite ones
        x = np.zeros((n, 3))
        x[1, 0] = inf
        assert np.asarray(inside(x, box)).tolist() == [w != 1 for w in range(n)]
        assert np.asarray(inside(x, box, G, h)).tolist() == [w != 1 for w in range(n)]



# A step of the any-robot fuzz (benchmarks/fuzz_any_robot.py --case 8850 --batched 1)
STEPS = Path(__file__).parents[1] / "data" / "fuzz_closed_form_steps.npz"


def test_an_answer_that_meets_its_rows_as_well_as_floats_can_is_kept():
    """A fuzz step whose closed-form answer is the QP's minimiser (an exact KKT solve in
    80 digits agrees to 3e-13), bounds held as at it, but whose residual the row-by-row
    1e-10 check refused in one run and not in the other (their roundings apart), the
    refused world going to a solver that did worse: step 20 of case 8850 (world 3: the
    batch's data), a soft row of terms |R_i||x| 2.3e8 for a target of 39, missed by
    1.7e-8, its rounding (ε |R_i||x| = 5e-8). Kept in one world and in four (the N-world
    arithmetic), the same answer."""
    d = {key.split("_", 1)[1]: value for key, value in np.load(STEPS).items() if key.startswith("8850")}
    R, rhs, damping, soft_rows = d["R"], d["rhs"], d["damping"], int(d["soft_rows"])
    nv, rows = R.shape[1], len(R) - soft_rows
    answers = []
    for n in (1, 4):
        def tile(a):
            return np.repeat(a[None], n, axis=0)

        cost = SimpleNamespace(dinv=tile(1.0 / damping), damping=tile(damping), R=tile(R), rhs=tile(rhs),
                               linear=tile(d["linear"]) if "linear" in d else None)
        held = HeldBounds(n, nv, soft_rows, rows)
        held.lower[:], held.upper[:], held.holding = d["held_lower"], d["held_upper"], True
        x, solved = held.solve(cost, tile(np.stack([d["lower"], d["upper"]])), tile(d["G"]), tile(d["h"]))
        assert solved.all(), n
        assert (held.lower == d["held_lower"]).all() and (held.upper == d["held_upper"]).all()  # no bound let go
        answers.append(x)
    np.testing.assert_allclose(answers[1], np.repeat(answers[0], 4, axis=0), rtol=0,
                               atol=1e-10 * np.abs(answers[0]).max())


@pytest.mark.parametrize("soft_rows, hard_rows", [(1, 0), (2, 0), (1, 1), (0, 2), (3, 2), (1, 3), (6, 1)])
@pytest.mark.parametrize("epsilon", [1e-10, 1e-3])
def test_the_damped_least_squares_step_is_the_kkt_solution(soft_rows, hard_rows, epsilon):
    """min ½‖R₁x − r₁‖² + ½xᵀDx + cᵀx s.t. R₂x = r₂ in 3 worlds, against the KKT system
    solved by NumPy: the rows met; both meet the soft rows equally well (the ε-direction
    may differ at ε = 1e-10, where the KKT matrix's condition reaches 1e10); at ε = 1e-3
    the same x."""
    rng = np.random.default_rng(soft_rows + 10 * hard_rows)
    n = 3
    step = DampedLeastSquares(n, NV, soft_rows, hard_rows)
    for _ in range(10):
        R = rng.normal(size=(n, soft_rows + hard_rows, NV))
        rhs, c = rng.normal(size=(n, soft_rows + hard_rows)), rng.normal(size=(n, NV)) * epsilon
        diagonal = epsilon * (1.0 + rng.random((n, NV)))
        x, _, ok = step.solve(1.0 / diagonal, R, rhs, c)
        assert np.all(ok)
        for w in range(n):
            R1, R2 = R[w, :soft_rows], R[w, soft_rows:]
            kkt = np.block([[R1.T @ R1 + np.diag(diagonal[w]), R2.T], [R2, np.zeros((hard_rows, hard_rows))]])
            expected = np.linalg.solve(kkt, np.concatenate([R1.T @ rhs[w, :soft_rows] - c[w],
                                                            rhs[w, soft_rows:]]))[:NV]
            np.testing.assert_allclose(R2 @ x[w], rhs[w, soft_rows:], atol=1e-12)
            residual = np.linalg.norm(R1 @ x[w] - rhs[w, :soft_rows]) - \
                np.linalg.norm(R1 @ expected - rhs[w, :soft_rows])
            assert abs(residual) <= 1e-9
            if epsilon > 1e-6:
                np.testing.assert_allclose(x[w], expected, rtol=1e-9, atol=1e-12)


def test_refinement_brings_back_the_digits_a_tiny_epsilon_loses(monkeypatch):
    """Equalities that fix x entirely, ε = 1e-10 (a hierarchy level whose bounds left as
    many free joints as rows above): x = D⁻¹(Rᵀz − c) is a difference of 1e10-sized terms.
    Without refinement the equalities are met to ~1e-6 relative, and the answer is
    refused; with it, every answer that is kept meets them to 1e-10 and is the point
    they fix (NumPy's solve of R₂x = r₂; R₂ 2×2 of normal entries: κ below 1e4 in all but
    a few draws, 1e-8 relative allowed)."""
    rng = np.random.default_rng(0)
    problems = [(rng.normal(size=(1, 3, 2)), 100.0 * rng.normal(size=(1, 3))) for _ in range(50)]
    step = DampedLeastSquares(1, 2, 1, 2)
    kept = 0
    for R, rhs in problems:
        x, _, ok = step.solve(np.full((1, 2), 1e10), R, rhs, np.zeros((1, 2)))
        if ok[0]:
            kept += 1
            expected = np.linalg.solve(R[0, 1:], rhs[0, 1:])
            assert np.linalg.norm(x[0] - expected) <= 1e-8 * np.linalg.norm(expected)
    assert kept >= 40
    monkeypatch.setattr(closed_form, "REFINEMENTS", 0)
    monkeypatch.setattr(closed_form, "EQUALITY_TOLERANCE", np.inf)
    misses = []
    for R, rhs in problems:
        x, _, ok = step.solve(np.full((1, 2), 1e10), R, rhs, np.zeros((1, 2)))
        if not ok[0]:  # declined on its pivots already
            continue
        misses.append(np.linalg.norm(R[0, 1:] @ x[0] - rhs[0, 1:]) / np.linalg.norm(rhs[0, 1:]))
    assert len(misses) >= 25 and np.median(misses) > 1e-8


def test_a_world_is_refined_only_where_its_own_residual_asks():
    """Refinement is a per-world decision: worlds that met the tolerance at once keep their
    first answer bit for bit when a neighbour in the same batch needs refining (a sweep's
    answers must not depend on how its worlds are chunked). Three well-damped worlds
    (ε = 1) beside one that loses digits (ε = 1e-10 with equalities fixing x), against
    the same three worlds solved without it."""
    rng = np.random.default_rng(3)
    R, rhs = rng.normal(size=(4, 3, 2)), 100.0 * rng.normal(size=(4, 3))
    dinv = np.ones((4, 2))
    dinv[0] = 1e10  # world 0 needs refinement
    batch = DampedLeastSquares(4, 2, 1, 2)
    x, _, ok = batch.solve(dinv, R, rhs, np.zeros((4, 2)))
    alone = DampedLeastSquares(3, 2, 1, 2)
    expected, _, ok_alone = alone.solve(dinv[1:], R[1:], rhs[1:], np.zeros((3, 2)))
    assert ok.all() and ok_alone.all()
    np.testing.assert_array_equal(x[1:], expected)  # exactly: the same operations on the same numbers


@pytest.mark.parametrize("soft_rows", [1, 2])
def test_each_row_is_judged_at_its_own_scale_beside_a_far_soft_target(monkeypatch, soft_rows):
    """A soft row's target 1e9 away must not excuse a near row's miss, hard (soft_rows 1)
    or soft (2): the first Cholesky solve is made to miss by 1e-6 in the near row (as
    rounding can on an ill-conditioned step: D⁻¹ = 1/ε with a far target lost 1e-5 so in
    the any-robot fuzz); the residual check, row by row, refines, and the answer returned
    meets the near row's equation to 1e-10 (1 + |r|). Judged against the whole right side
    (1e9), the miss passed unrefined."""
    real, calls = closed_form.cholesky_substitute, []

    def first_misses(factor, B, *args, **kwargs):
        X = real(factor, B, *args, **kwargs)
        if not calls:
            X[:, 1] += 1e-6
        calls.append(1)
        return X

    monkeypatch.setattr(closed_form, "cholesky_substitute", first_misses)
    R = np.array([[[1.0, 0.5, 0.0], [0.0, 1.0, 1.0]]])  # the far soft row, then the near row
    rhs = np.array([[1e9, 2.0]])
    form = DampedLeastSquares(1, 3, soft_rows, 2 - soft_rows)
    x, z, ok = form.solve(np.ones((1, 3)), R, rhs, np.zeros((1, 3)))
    assert ok.all() and len(calls) > 1  # refined
    near = R[0, 1] @ x[0] + (z[0, 1] if soft_rows == 2 else 0.0)  # R₁x + z₁ = r₁ on a soft row
    assert abs(near - rhs[0, 1]) <= 1e-10 * (1.0 + abs(rhs[0, 1]))


@pytest.mark.parametrize("solver", ["daqp", "quadprog"])
def test_a_far_target_gets_the_solvers_capped_cost(solver):
    """A posture target 1e12 rad away makes c ~1e14: the closed form leaves the step to the
    solver, which sees c capped at 1e9 times H's scale (docs/controllers.md), so the answer
    is −H⁻¹ c_capped, written out (the uncapped minimiser is ~1e14 rad/s); the next
    ordinary step is the closed form's again (no solver call)."""
    robot = Robot.load("arm")
    near = robot.q.copy()
    posture = PostureTask(robot, gain=100.0, weight=1.0)
    posture.set_target(near + 1e12)
    qp = QPController(robot, [posture, DampingTask(robot, weight=1e-3)], [], solver=solver, dt=0.002)
    answer = np.array(qp.compute_velocity())
    assert qp.solver_calls == 1
    diagonal = np.full(robot.nv, 1.0 + 1e-3 + 1e-12)
    c = -100.0 * np.array(posture.error)
    expected = -(c * (1e9 * diagonal.max() / np.abs(c).max())) / diagonal
    # Norm-wise: the capped minimiser's scale is ~1e9; to the capped cost's 1e-9 relative.
    assert np.linalg.norm(answer - expected) <= 1e-9 * np.linalg.norm(expected)
    posture.set_target(near + 0.1)
    np.testing.assert_allclose(qp.compute_velocity(), 100.0 * 0.1 / diagonal, rtol=1e-12)
    assert qp.solver_calls == 1  # the closed form's again, at once


@pytest.mark.parametrize("scenario", ["seed-redundant", "joint-limits", "unreachable", "hexapod-position-only"])
def test_every_step_of_a_scenario_is_its_qps_minimiser(scenario):
    """The bundled scenarios' QP runs, every 8th step checked (hundreds per run): the answer equals the
    minimiser of its QP solved independently (the tasks' rows and the limits' box written
    out, DAQP called directly and made exact: 1e-9 relative). Where limits bind, the
    closed form holds the binding bounds and the solver takes fewer steps than they bind."""
    setup = build_scenario(scenario)
    controller = setup.controller("qp", "daqp")
    robot, steps = setup.robot, int(round(setup.duration / setup.dt))
    binding = 0
    for k in range(steps):
        setup.reference.apply(k * setup.dt)
        qdot = np.array(controller.compute_velocity())
        binding += bool(np.any(np.isclose(qdot, controller.lb, rtol=1e-9, atol=0) |
                               np.isclose(qdot, controller.ub, rtol=1e-9, atol=0)))
        if k % 8 == 0:
            lower, upper, G, h = references.limits_box(controller.limits, setup.dt, 1, robot.nv)
            expected = references.qp_answer(controller.tasks, 0, robot.nv, (lower[0], upper[0]), (G[0], h[0]))
            assert references.close(qdot, expected, 1e-9), (k, qdot, expected)
        robot.integrate(qdot, setup.dt)
    if scenario in ("joint-limits", "unreachable"):
        assert 0 < binding < steps and controller.solver_calls < binding


def test_a_tolerance_solvers_answer_on_wrong_bounds_is_replaced_by_the_minimiser():
    """Any-robot case 9190: ½ q̇ᵀDq̇ + c₀ᵀq̇ with D 0.026 on 12 dofs and the 1e-12
    regulariser alone on 3, 3 hard rows that drive those 3 to 1.5e7, a box and a collision
    row. ProxQP's answer (stored, from a run in which its workspaces' alignment made it
    so; the batch's world got the minimiser) holds two bounds the minimiser does not hold
    and costs 2% more. The held-bounds iteration from its bounds (``HeldBounds.polish``)
    gives the minimiser: the cost of DAQP's answer on the same QP, an exact solver's, to
    1e-9 (the cost's terms are of its own size: ½ q̇ᵀDq̇ is 194, c₀ᵀq̇ 0.05), on the same
    bounds."""
    from qpik.solvers import make_backend

    step = dict(np.load(Path(__file__).resolve().parents[1] / "data" / "rescued_step.npz"))
    D, c0, A, b, lb, ub, G, h = (step[k] for k in ("D", "c0", "A", "b", "lb", "ub", "G", "h"))
    nv, meq = len(D), len(A)
    exact = make_backend("daqp", nv, meq, len(h))
    exact.A[:], exact.b[:], exact.G[:], exact.h[:], exact.lb[:], exact.ub[:] = A, b, G, h, lb, ub
    reference = exact.solve(np.diag(D), c0)
    cost = SimpleNamespace(dinv=1.0 / D[None], damping=D[None], R=A[None], rhs=b[None], linear=c0[None])
    held = HeldBounds(1, nv, 0, meq, hold=False)
    x = held.polish(cost, np.stack([lb, ub])[None], G[None], h[None], 0, step["proxqp"])

    def objective(v):
        return 0.5 * v @ (D * v) + c0 @ v

    assert objective(step["proxqp"]) > 1.01 * objective(reference)
    assert abs(objective(x) - objective(reference)) <= 1e-9 * objective(reference)
    assert all(np.array_equal(a, r) for a, r in zip(closed_form.active_bounds(x, lb, ub),
                                                    closed_form.active_bounds(reference, lb, ub)))
    assert np.abs(A @ x - b).max() <= 1e-9 * (1 + np.abs(A) @ np.abs(x)).max() and inside(x[None], np.stack([lb, ub])[None])[0]
