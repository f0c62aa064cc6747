r"""QP solver back-ends, chosen by their qpsolvers name.

Every back-end solves

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\; lb \le x \le ub

with fixed sizes (nv variables, meq equalities) decided once. DAQP and OSQP are
called through their own Python interfaces so the control loop pays no per-call
conversion: DAQP takes the dense arrays as they are (bounds as simple bounds), and
one OSQP workspace is set up once with a fixed sparsity pattern, then updated and
warm-started every step. Any other solver that qpsolvers knows runs through
``qpsolvers.solve_problem``.
"""

from __future__ import annotations

from ctypes import c_int

import numpy as np
import qpsolvers

from .errors import InfeasibleProblem, InvalidInput, SolverError, UnknownName

_BIG = 1e30  # DAQP's and OSQP's stand-in for an absent bound


def available_solvers() -> list[str]:
    """Names of the QP solvers installed here (qpsolvers' names)."""
    return sorted(qpsolvers.available_solvers)


class QPBackend:
    """Base class: one solver instance per controller, sized at construction."""

    name = "qp"

    def __init__(self, nv: int, meq: int):
        self.nv = nv
        self.meq = meq

    def solve(self, H, c, A, b, lb, ub) -> np.ndarray:
        raise NotImplementedError

    def _fail(self, status: str, infeasible: bool) -> None:
        if infeasible:
            raise InfeasibleProblem(
                f"QP infeasible ({self.name}: {status}): the hard tasks and limits cannot all be met"
            )
        raise SolverError(f"QP solver {self.name} failed: {status}")


class DaqpBackend(QPBackend):
    """DAQP (dual active set, dense): bounds as simple bounds, equalities by ``sense``."""

    name = "daqp"
    _EXIT = {-1: "primal infeasible", -2: "cycling detected", -3: "unbounded problem",
             -4: "iteration limit reached", -5: "nonconvex problem", -6: "overdetermined initial active set"}

    def __init__(self, nv: int, meq: int, **settings):
        super().__init__(nv, meq)
        import daqp

        self._solve = daqp.solve
        self._settings = settings
        self._upper = np.empty(nv + meq)
        self._lower = np.empty(nv + meq)
        self._sense = np.zeros(nv + meq, dtype=c_int)
        self._sense[nv:] = 5  # equality rows
        self._no_rows = np.zeros((0, nv))

    def solve(self, H, c, A, b, lb, ub) -> np.ndarray:
        nv = self.nv
        np.clip(ub, -_BIG, _BIG, out=self._upper[:nv])
        np.clip(lb, -_BIG, _BIG, out=self._lower[:nv])
        self._upper[nv:] = b
        self._lower[nv:] = b
        x, _, exitflag, _ = self._solve(H, c, A if self.meq else self._no_rows, self._upper, self._lower,
                                        self._sense, **self._settings)
        if exitflag < 1:
            self._fail(self._EXIT.get(exitflag, f"exit flag {exitflag}"), exitflag == -1)
        return x


class OsqpBackend(QPBackend):
    """One OSQP workspace, updated in place and warm-started each step.

    The constraint matrix is [A; I] with l = [b; lb], u = [b; ub]. Its sparsity
    pattern (dense A block, identity) and the dense upper triangle of H are fixed at
    setup, so each step only overwrites the numeric values.
    """

    name = "osqp"
    SETTINGS = dict(eps_abs=1e-9, eps_rel=1e-9, polishing=True, max_iter=20000, verbose=False,
                    warm_starting=True, adaptive_rho=True)

    def __init__(self, nv: int, meq: int, **settings):
        super().__init__(nv, meq)
        import osqp
        import scipy.sparse as sp

        self._osqp = osqp
        self._settings = {**self.SETTINGS, **settings}
        rows_p, cols_p = np.triu_indices(nv)
        order = np.lexsort((rows_p, cols_p))  # CSC: column-major, rows sorted
        self._p_rows, self._p_cols = rows_p[order], cols_p[order]
        eq_r, eq_c = np.meshgrid(np.arange(meq), np.arange(nv), indexing="ij")
        a_rows = np.concatenate([eq_r.ravel(), meq + np.arange(nv)])
        a_cols = np.concatenate([eq_c.ravel(), np.arange(nv)])
        order = np.lexsort((a_rows, a_cols))
        self._a_rows, self._a_cols = a_rows[order], a_cols[order]
        self._stacked = np.zeros((meq + nv, nv))
        self._stacked[meq:] = np.eye(nv)
        self._lower = np.empty(meq + nv)
        self._upper = np.empty(meq + nv)
        self._sp = sp
        self._solver = None

    def _matrices(self, H):
        p_data = H[self._p_rows, self._p_cols]
        a_data = self._stacked[self._a_rows, self._a_cols]
        return p_data, a_data

    def solve(self, H, c, A, b, lb, ub) -> np.ndarray:
        meq = self.meq
        if meq:
            self._stacked[:meq] = A
        self._lower[:meq] = b
        self._upper[:meq] = b
        np.clip(lb, -_BIG, _BIG, out=self._lower[meq:])
        np.clip(ub, -_BIG, _BIG, out=self._upper[meq:])
        p_data, a_data = self._matrices(H)
        if self._solver is None:
            n, m = self.nv, meq + self.nv
            # Explicit zeros are kept: the pattern must not change between updates.
            P = self._pattern(p_data, self._p_rows, self._p_cols, n, n)
            Am = self._pattern(a_data, self._a_rows, self._a_cols, m, n)
            self._solver = self._osqp.OSQP()
            self._solver.setup(P, c.copy(), Am, self._lower.copy(), self._upper.copy(), **self._settings)
        else:
            self._solver.update(q=c, l=self._lower, u=self._upper, Px=p_data, Ax=a_data)
        result = self._solver.solve(raise_error=False)
        status = result.info.status_val
        Status = self._osqp.SolverStatus
        if status != Status.OSQP_SOLVED:
            infeasible = status in (Status.OSQP_PRIMAL_INFEASIBLE, Status.OSQP_PRIMAL_INFEASIBLE_INACCURATE)
            self._fail(result.info.status, infeasible)
        return result.x

    def _pattern(self, data, rows, cols, m, n):
        """CSC matrix with exactly the given (column-major sorted) entries, zeros kept."""
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.add.at(indptr, cols + 1, 1)
        return self._sp.csc_matrix((data, rows, np.cumsum(indptr)), shape=(m, n))


class QpsolversBackend(QPBackend):
    """Any solver qpsolvers supports (quadprog, proxqp, clarabel, ...), called per step."""

    def __init__(self, nv: int, meq: int, solver: str, **settings):
        super().__init__(nv, meq)
        self.name = solver
        self._settings = settings

    def solve(self, H, c, A, b, lb, ub) -> np.ndarray:
        finite_lb = np.where(np.isfinite(lb), lb, -_BIG)
        finite_ub = np.where(np.isfinite(ub), ub, _BIG)
        problem = qpsolvers.Problem(H, c, None, None, A if self.meq else None, b if self.meq else None,
                                    finite_lb, finite_ub)
        try:
            solution = qpsolvers.solve_problem(problem, solver=self.name, **self._settings)
        except Exception as exc:  # solver-specific exceptions: report, don't traceback
            raise SolverError(f"QP solver {self.name} failed: {type(exc).__name__}: {exc}") from None
        if not solution.found or solution.x is None:
            self._fail("no solution found (infeasible constraints or solver failure)", False)
        return solution.x


def make_backend(solver: str, nv: int, meq: int, native: bool = True, **settings) -> QPBackend:
    """Back-end for a qpsolvers solver name; ``native=False`` forces the qpsolvers path."""
    if not isinstance(solver, str) or solver not in qpsolvers.available_solvers:
        raise UnknownName(f"unknown or uninstalled QP solver {solver!r}; available: {available_solvers()}")
    if nv < 1 or meq < 0:
        raise InvalidInput("a QP needs at least one variable")
    if native and solver == "daqp":
        return DaqpBackend(nv, meq, **settings)
    if native and solver == "osqp":
        return OsqpBackend(nv, meq, **settings)
    if solver == "osqp":
        settings = {**OsqpBackend.SETTINGS, **settings}
        settings.pop("warm_starting", None)
    settings = {**_QPSOLVERS_DEFAULTS.get(solver, {}), **settings}
    return QpsolversBackend(nv, meq, solver, **settings)


# Tolerances tight enough for the QP to reproduce the closed-form laws (≤ 1e-6).
_QPSOLVERS_DEFAULTS = {"proxqp": {"eps_abs": 1e-10, "eps_rel": 0.0}}
