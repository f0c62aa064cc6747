"""A solver that will not converge costs its iteration cap once, not every step: it sits
out the next steps after a failure, leaves no iterate behind for the next one, and is not
run to its cap twice on one step. (Work is counted in solver calls and iterations here,
never in time.)"""

from __future__ import annotations

import numpy as np
import pytest

from qpik.controllers.fallbacks import GuardedSolve
from qpik.errors import QpikError, SolverError
from qpik.solvers import available_solvers, make_backend

needs = pytest.mark.skipif(not {"osqp", "proxqp"} <= set(available_solvers()), reason="the solvers extra")


def _box_problem(backend) -> tuple[np.ndarray, np.ndarray]:
    backend.A[:] = [[1.0, 1.0, 0.0]]
    backend.b[:] = [0.5]
    backend.lb[:], backend.ub[:] = -0.2, 0.4
    return np.diag([1.0, 2.0, 3.0]), np.array([1.0, -3.0, 0.5])


class _Counted:
    """A callable that counts its calls."""

    def __init__(self, function):
        self.function, self.calls = function, 0

    def __call__(self, *args, **kwargs):
        self.calls += 1
        return self.function(*args, **kwargs)


@needs
def test_a_solver_that_failed_sits_out_the_next_steps():
    """OSQP held to one iteration fails every solve; DAQP answers instead (with the
    guard's 1e-9 of damping). After the first failure OSQP sits out 8 steps, then is
    tried again (and fails again)."""
    backend = make_backend("osqp", 3, 1, 0, max_iter=1)
    H, c = _box_problem(backend)
    backend._solve = counted = _Counted(backend._solve)
    guard = GuardedSolve(backend, "osqp")
    reference = make_backend("daqp", 3, 1, 0)
    _box_problem(reference)
    expected = reference.solve(H, c)
    for _ in range(10):
        np.testing.assert_allclose(guard.solve(H, c), expected, rtol=1e-8, atol=1e-12)
    assert counted.calls == 2  # steps 0 and 9
    assert guard.fallbacks == 10


@needs
def test_a_failed_osqp_solve_leaves_no_iterate_for_the_next_step():
    """After a solve that ran out of iterations, the next problem is solved as by a fresh
    workspace (a warm start from the failed run's iterates took every later step of an
    85-dof model to the cap)."""
    rng = np.random.default_rng(0)
    nv, meq = 6, 2
    A, x0 = rng.normal(size=(meq, nv)), rng.normal(size=nv)
    H, c = np.eye(nv), rng.normal(size=nv)

    def fill(backend, margin):
        backend.A[:], backend.b[:] = A, A @ x0
        backend.lb[:], backend.ub[:] = x0 - margin, x0 + margin

    for _ in range(500):  # a nearly singular, badly scaled problem OSQP does not finish
        used = make_backend("osqp", nv, meq, 0)
        fill(used, rng.uniform(0.0, 1.0, nv))
        try:
            used.solve(np.diag(10.0 ** rng.uniform(-12, -6, nv)), rng.normal(size=nv) * 10.0 ** rng.uniform(0, 6))
        except SolverError:
            break
    else:
        pytest.fail("no problem made OSQP run out of iterations")
    fresh = make_backend("osqp", nv, meq, 0)
    fill(used, 1.0)
    fill(fresh, 1.0)
    np.testing.assert_array_equal(used.solve(H, c), fresh.solve(H, c))


class _CountingQP:
    """A proxsuite QP whose solve() calls are counted."""

    def __init__(self, qp):
        self.__dict__["_qp"], self.__dict__["solves"] = qp, 0

    def solve(self):
        self.__dict__["solves"] += 1
        return self._qp.solve()

    def __getattr__(self, name):
        return getattr(self._qp, name)


@needs
def test_proxqp_is_not_run_to_its_cap_twice_on_one_step():
    """A warm start that runs out of iterations fails the step (the guard's exact solvers
    take it); only a warm start that claims infeasibility is tried again from cold."""
    backend = make_backend("proxqp", 3, 1, 0)
    H, c = _box_problem(backend)
    backend.solve(H, c)  # warm from here on
    backend._qp = counting = _CountingQP(backend._qp)
    counting.settings.max_iter = 1
    with pytest.raises(QpikError, match="MAX_ITER"):
        backend.solve(H, c + 1.0)
    assert counting.solves == 1
