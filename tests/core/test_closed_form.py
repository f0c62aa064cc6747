"""The closed-form fast path returns the solver's answer: checked step by step against
the solver on the bundled scenarios, on random equality-constrained QPs, and with the
bounds a solver found active held (random boxed QPs)."""

from __future__ import annotations

import numpy as np
import pytest

from qpik.limits import Limit
from qpik.problem import Inequalities, backoff, closed_form
from qpik.problem.closed_form import HeldBounds, closed_form_step, damped_least_squares_step
from qpik.scenario import build_scenario
from qpik.solvers import make_backend


@pytest.mark.parametrize("scenario", ["seed-redundant", "joint-limits", "unreachable", "hexapod-position-only"])
def test_fast_path_equals_the_solver_step_by_step(scenario):
    fast_setup, slow_setup = build_scenario(scenario), build_scenario(scenario)
    fast = fast_setup.controller("qp", "daqp")
    slow = slow_setup.controller("qp", "daqp", fast_path=False)
    steps = int(round(fast_setup.duration / fast_setup.dt))
    worst, box_differs, binding = 0.0, 0, 0
    for k in range(steps):
        t = k * fast_setup.dt
        for setup in (fast_setup, slow_setup):
            setup.reference.apply(t)
        slow_setup.robot.set_q(fast_setup.robot.q)  # same state for both
        a, b = fast.compute_velocity(), slow.compute_velocity()
        worst = max(worst, float(np.max(np.abs(a - b)) / (1.0 + np.max(np.abs(b)))))
        box_differs += not (np.array_equal(fast.lb, slow.lb) and np.array_equal(fast.ub, slow.ub))
        binding += bool(np.any(np.isclose(b, slow.lb, rtol=1e-9, atol=0) | np.isclose(b, slow.ub, rtol=1e-9, atol=0)))
        fast_setup.robot.integrate(a, fast_setup.dt)
    assert worst <= 1e-12
    assert box_differs == 0
    assert slow.solver_calls == steps
    if scenario in ("joint-limits", "unreachable"):
        # Limits bind on some steps: the closed form holds the binding bounds there (its
        # KKT check passed), and the solver takes fewer steps than they bind on.
        assert 0 < binding < steps and fast.solver_calls < binding


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
        step = closed_form_step(nv, meq, None if hessian == "per-call" else H)
        x = step.solve(H, np.vstack([A, c]), b)
        backend = make_backend("daqp", nv, meq)
        backend.A[:], backend.b[:] = A, b
        np.testing.assert_allclose(x, backend.solve(H, c), rtol=1e-10, atol=1e-10)


def test_dependent_hard_rows_are_left_to_the_solver():
    H = np.eye(3)
    A = np.array([[1.0, 2.0, 0.0], [2.0, 4.0, 0.0]])  # the same row twice
    for meq_rows in (A, np.vstack([A, [[0.0, 0.0, 1.0]]])):
        Ac = np.vstack([meq_rows, np.zeros(3)])
        assert closed_form_step(3, len(meq_rows), H).solve(H, Ac, np.ones(len(meq_rows))) is None


@pytest.mark.parametrize("soft_rows, hard_rows", [(1, 0), (2, 0), (1, 1), (0, 2), (3, 2), (1, 3), (6, 1)])
@pytest.mark.parametrize("epsilon", [1e-10, 1e-3])
def test_damped_least_squares_step_is_the_kkt_solution(soft_rows, hard_rows, epsilon):
    """min ½‖R₁x − r₁‖² + ½xᵀDx + cᵀx s.t. R₂x = r₂, against the KKT system solved in
    extended precision-free form (numpy's lstsq on the bordered matrix)."""
    rng = np.random.default_rng(soft_rows + 10 * hard_rows)
    nv = 7
    for _ in range(20):
        R = rng.normal(size=(soft_rows + hard_rows, nv))
        rhs, c = rng.normal(size=soft_rows + hard_rows), rng.normal(size=nv) * epsilon
        diagonal = epsilon * (1.0 + rng.random(nv))
        x = damped_least_squares_step(1.0 / diagonal, R, soft_rows, rhs, c)
        R1, R2 = R[:soft_rows], R[soft_rows:]
        kkt = np.block([[R1.T @ R1 + np.diag(diagonal), R2.T], [R2, np.zeros((hard_rows, hard_rows))]])
        expected = np.linalg.solve(kkt, np.concatenate([R1.T @ rhs[:soft_rows] - c, rhs[soft_rows:]]))[:nv]
        assert x is not None
        np.testing.assert_allclose(R2 @ x, rhs[soft_rows:], atol=1e-12)
        # both meet the soft rows equally well (the ε-direction may differ at ε = 1e-10)
        residual = np.linalg.norm(R1 @ x - rhs[:soft_rows]) - np.linalg.norm(R1 @ expected - rhs[:soft_rows])
        assert abs(residual) <= 1e-9
        if epsilon > 1e-6:
            np.testing.assert_allclose(x, expected, rtol=1e-9, atol=1e-12)


def test_damped_least_squares_step_refuses_an_answer_that_misses_the_equalities(monkeypatch):
    """Equalities that fix x entirely, ε = 1e-10 (a hierarchy level whose bounds left as
    many free joints as rows above): the soft rows' Schur complement is a difference of
    1e10-sized terms. Unguarded, the equalities are met to ~1e-6 relative; guarded, the
    step declines (None) and the solver takes the level."""
    rng = np.random.default_rng(0)
    problems = [(rng.normal(size=(3, 2)), 100.0 * rng.normal(size=3)) for _ in range(50)]
    assert all(damped_least_squares_step(np.full(2, 1e10), R, 1, rhs, np.zeros(2)) is None for R, rhs in problems)
    monkeypatch.setattr(closed_form, "EQUALITY_TOLERANCE", np.inf)
    misses = []
    for R, rhs in problems:
        x = damped_least_squares_step(np.full(2, 1e10), R, 1, rhs, np.zeros(2))
        if x is None:  # declined on its pivots already
            continue
        misses.append(np.linalg.norm(R[1:] @ x - rhs[1:]) / np.linalg.norm(rhs[1:]))
    assert len(misses) >= 25 and np.median(misses) > 1e-8


def test_the_pause_doubles_after_each_failure_and_resets_after_a_success():
    fast = closed_form.ClosedForm(admits=None)
    tried = []
    for step in range(200):  # every attempt fails: tried at 0, then after 8, 16, 32, 32, ... steps
        fast.attempt(lambda step=step: tried.append(step))  # None: a miss
    assert tried[:5] == [0, 9, 26, 59, 92]
    assert all(b - a == backoff.PAUSE_MAX + 1 for a, b in zip(tried[3:], tried[4:]))
    fast.skip = 0
    x = np.zeros(2)
    assert fast.attempt(lambda: x) is x  # tried now, and a success
    fast.attempt(lambda: None)
    assert fast.skip == backoff.PAUSE  # the pause after it back at its start


class _Box(Limit):
    """A fixed box, written every step (a changing limit, arrays only)."""

    def __init__(self, lower: np.ndarray, upper: np.ndarray):
        self.lower, self.upper = lower, upper

    def apply(self, dt, lb, ub, G=None, h=None):
        np.maximum(lb, self.lower, out=lb)
        np.minimum(ub, self.upper, out=ub)


@pytest.mark.parametrize("hessian", ["diagonal", "dense"])
@pytest.mark.parametrize("meq", [0, 1, 3])
def test_held_bounds_give_the_solvers_minimiser_or_nothing(hessian, meq):
    """Random strictly convex QPs in a tight box, against DAQP: held at the bounds the
    solver found active, the closed form returns its minimiser; held at any other set it
    returns that minimiser (after releasing and holding bounds) or None, never another
    point: the KKT check decides."""
    rng = np.random.default_rng(10 + meq)
    nv, held_right, wrong_kept = 7, 0, 0
    for trial in range(40):
        M = rng.normal(size=(nv, nv))
        H = np.diag(rng.uniform(0.5, 2.0, nv)) if hessian == "diagonal" else M @ M.T + 0.1 * np.eye(nv)
        Ac, b = rng.normal(size=(meq + 1, nv)), 0.1 * rng.normal(size=meq)
        Ac[meq] *= 3.0  # a cost that pulls out of the box
        inequalities = Inequalities(nv, [_Box(np.full(nv, -0.5), np.full(nv, 0.5))], 0.01)
        inequalities.write()
        backend = make_backend("daqp", nv, meq)
        backend.A[:], backend.b[:] = Ac[:meq], b
        backend.lb[:], backend.ub[:] = inequalities.lb, inequalities.ub
        expected = backend.solve(H, Ac[meq].copy())
        held = HeldBounds(nv, meq, closed_form_step(nv, meq, H if hessian == "diagonal" else None), inequalities)
        held.remember(expected)
        x = held.solve(H, Ac, b)
        assert x is not None
        np.testing.assert_allclose(x, expected, rtol=0, atol=1e-9)
        held_right += bool(held.lower or held.upper)
        held.lower, held.upper = rng.permutation(nv)[:2].tolist(), [int(rng.integers(nv))]  # a guess
        held.upper = [i for i in held.upper if i not in held.lower]
        x = held.solve(H, Ac, b)
        if x is not None:
            np.testing.assert_allclose(x, expected, rtol=0, atol=1e-9)
            wrong_kept += 1
    assert held_right >= 30  # the box binds on most problems
    assert wrong_kept >= 1  # and a wrong guess is repaired by the active-set steps at times


@pytest.mark.parametrize("solver", ["daqp", "quadprog"])
def test_a_far_target_gets_the_solvers_capped_cost_on_the_fast_path_too(solver):
    """A posture target 1e12 rad away makes c ~1e14: the solver's step sees c capped
    (GuardedSolve tames it), so the closed form must not answer with the uncapped
    minimiser, or the two paths would move the robot 1e5 times apart."""
    from qpik import DampingTask, PostureTask, QPController, Robot

    answers = []
    for fast_path in (True, False):
        robot = Robot.load("arm")
        posture = PostureTask(robot, gain=100.0, weight=1.0)
        posture.set_target(robot.q + 1e12)
        qp = QPController(robot, [posture, DampingTask(robot, weight=1e-3)], [], solver=solver, dt=0.002,
                          fast_path=fast_path)
        answers.append(qp.compute_velocity().copy())
    assert np.abs(answers[1]).max() < 1e10  # capped: the uncapped minimiser is ~1e14 rad/s
    # Norm-wise: the capped minimiser's scale is |c|/|H| ~1e9; the two paths agree to the
    # capped cost's 1e-9 relative (docs/controllers.md), whatever a small entry rounds to.
    assert np.linalg.norm(answers[0] - answers[1]) <= 1e-9 * np.linalg.norm(answers[1])


def test_a_capped_step_starts_no_pause_of_the_closed_form():
    """A step whose cost the solver caps goes to the solver, but it is no miss of the closed
    form: the next ordinary step is solved in closed form again (no solver call)."""
    from qpik import DampingTask, PostureTask, QPController, Robot

    robot = Robot.load("arm")
    posture = PostureTask(robot, gain=100.0, weight=1.0)
    qp = QPController(robot, [posture, DampingTask(robot, weight=1e-3)], [], solver="daqp", dt=0.002)
    near = robot.q.copy()
    posture.set_target(near + 1e12)
    qp.compute_velocity()
    assert qp.solver_calls == 1  # capped: the solver's step
    posture.set_target(near + 0.1)
    qp.compute_velocity()
    assert qp.solver_calls == 1  # the closed form's again, at once
