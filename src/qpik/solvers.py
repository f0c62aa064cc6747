r"""QP solver back-ends, chosen by their qpsolvers name.

Every back-end solves

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,\; lb \le x \le ub

with fixed sizes (nv variables, meq equalities) decided once. DAQP and OSQP are
called through their own Python interfaces so the control loop pays no per-call
conversion: DAQP takes the dense arrays as they are (bounds as simple bounds), one
OSQP workspace is set up once with a fixed sparsity pattern, and one ProxQP dense
workspace (native box constraints); both are updated and warm-started every step. Any other solver that qpsolvers knows runs through
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
    """Base class: one solver instance per controller, sized at construction.

    The controller writes the problem straight into the back-end's own arrays
    ``A`` (meq x nv), ``b`` (meq), ``lb`` and ``ub`` (nv; ±inf for no bound), laid
    out as the solver wants them, then calls :meth:`solve` with H and c.
    """

    name = "qp"
    exact_bounds = False  # interior-point/ADMM solvers meet bounds only to a tolerance

    def __init__(self, nv: int, meq: int):
        self.nv = nv
        self.meq = meq
        self.A = np.zeros((meq, nv))
        self.b = np.zeros(meq)
        self.lb = np.full(nv, -np.inf)
        self.ub = np.full(nv, np.inf)

    def solve(self, H: np.ndarray, c: np.ndarray, hessian_changed: bool = True) -> np.ndarray:
        """Solve with the arrays as written; ``hessian_changed=False`` lets a
        workspace keep its factorised H from the previous step."""
        raise NotImplementedError

    def _fail(self, status: str, infeasible: bool) -> None:
        if infeasible:
            raise InfeasibleProblem(
                f"QP infeasible ({self.name}: {status}): the hard tasks and limits cannot all be met"
            )
        raise SolverError(f"QP solver {self.name} failed: {status}")


class DaqpBackend(QPBackend):
    """DAQP (dual active set, dense): bounds as simple bounds, equalities by ``sense``.

    DAQP's bound vectors are [lb; b] and [ub; b]; ``lb``, ``ub`` and ``b`` are views
    into them.
    """

    name = "daqp"
    exact_bounds = True  # active set: an active bound holds exactly
    _EXIT = {-1: "primal infeasible", -2: "cycling detected", -3: "unbounded problem",
             -4: "iteration limit reached", -5: "nonconvex problem", -6: "overdetermined initial active set"}

    def __init__(self, nv: int, meq: int, **settings):
        super().__init__(nv, meq)
        import daqp

        self._solve = daqp.solve
        self._settings = settings
        self._upper = np.full(nv + meq, np.inf)
        self._lower = np.full(nv + meq, -np.inf)
        self.lb, self.ub, self.b = self._lower[:nv], self._upper[:nv], self._upper[nv:]
        self._b_lower = self._lower[nv:]
        self._sense = np.zeros(nv + meq, dtype=c_int)
        self._sense[nv:] = 5  # equality rows

    def solve(self, H, c, hessian_changed: bool = True) -> np.ndarray:
        self._b_lower[:] = self.b
        x, _, exitflag, _ = self._solve(H, c, self.A, self._upper, self._lower, self._sense, **self._settings)
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
    SETTINGS = dict(eps_abs=1e-8, eps_rel=1e-8, polishing=False, max_iter=20000, verbose=False,
                    warm_starting=True, adaptive_rho=True)

    def __init__(self, nv: int, meq: int, **settings):
        super().__init__(nv, meq)
        import osqp
        import scipy.sparse as sp

        self._osqp = osqp
        self._sp = sp
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
        self._lower = np.full(meq + nv, -np.inf)
        self._upper = np.full(meq + nv, np.inf)
        self.A = self._stacked[:meq]
        self.b, self._b_lower = self._upper[:meq], self._lower[:meq]
        self.lb, self.ub = self._lower[meq:], self._upper[meq:]
        self._solver = None
        self._workspace = None

    def solve(self, H, c, hessian_changed: bool = True) -> np.ndarray:
        self._b_lower[:] = self.b
        p_data = H[self._p_rows, self._p_cols] if hessian_changed or self._solver is None else None
        a_data = self._stacked[self._a_rows, self._a_cols]
        lower = np.maximum(self._lower, -_BIG)
        upper = np.minimum(self._upper, _BIG)
        if self._solver is None:
            n, m = self.nv, self.meq + self.nv
            # Explicit zeros are kept: the pattern must not change between updates.
            P = self._pattern(p_data, self._p_rows, self._p_cols, n, n)
            Am = self._pattern(a_data, self._a_rows, self._a_cols, m, n)
            self._solver = self._osqp.OSQP()
            self._solver.setup(P, c.copy(), Am, lower, upper, **self._settings)
            # The compiled workspace, when this osqp exposes it: its Python wrapper's
            # update() and solve() add ~20 µs a step (bound clipping through constant
            # lookups, a namespace of every info field) around a ~10 µs solve.
            self._workspace = getattr(self._solver, "_solver", None)
        elif self._workspace is not None:
            self._workspace.update_data_vec(q=c, l=lower, u=upper)
            self._workspace.update_data_mat(P_x=p_data, P_i=None, A_x=a_data, A_i=None)
        elif p_data is None:
            self._solver.update(q=c, l=lower, u=upper, Ax=a_data)
        else:
            self._solver.update(q=c, l=lower, u=upper, Px=p_data, Ax=a_data)
        if self._workspace is not None:
            self._workspace.solve()
            info, x = self._workspace.info, self._workspace.solution.x
        else:
            result = self._solver.solve(raise_error=False)
            info, x = result.info, result.x
        status = info.status_val
        Status = self._osqp.SolverStatus
        # "Solved inaccurate" (the iteration limit hit with a relaxed tolerance) is kept
        # when the constraints hold: only optimality is a little off (dual residual).
        inaccurate_but_feasible = status == Status.OSQP_SOLVED_INACCURATE and info.prim_res <= 1e-9
        if status != Status.OSQP_SOLVED and not inaccurate_but_feasible:
            infeasible = status in (Status.OSQP_PRIMAL_INFEASIBLE, Status.OSQP_PRIMAL_INFEASIBLE_INACCURATE)
            self._fail(str(info.status), infeasible)
        return np.array(x)  # the workspace reuses its solution buffer

    def _pattern(self, data, rows, cols, m, n):
        """CSC matrix with exactly the given (column-major sorted) entries, zeros kept."""
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.add.at(indptr, cols + 1, 1)
        return self._sp.csc_matrix((data, rows, np.cumsum(indptr)), shape=(m, n))


class ProxqpBackend(QPBackend):
    """One ProxQP dense workspace (box constraints native), updated and warm-started."""

    name = "proxqp"

    def __init__(self, nv: int, meq: int, eps_abs: float = 1e-10, eps_rel: float = 0.0, **settings):
        super().__init__(nv, meq)
        import proxsuite

        self._proxqp = proxsuite.proxqp
        self._qp = proxsuite.proxqp.dense.QP(nv, meq, 0, True)
        self._qp.settings.eps_abs = eps_abs
        self._qp.settings.eps_rel = eps_rel
        self._qp.settings.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        for key, value in settings.items():
            setattr(self._qp.settings, key, value)
        self._ready = False

    def solve(self, H, c, hessian_changed: bool = True) -> np.ndarray:
        lb = np.maximum(self.lb, -_BIG)
        ub = np.minimum(self.ub, _BIG)
        A, b = self.A, self.b  # (0, nv) and (0,) without equalities
        Output = self._proxqp.QPSolverOutput
        if self._ready:
            self._qp.update(H if hessian_changed else None, c, A, b, None, None, None, lb, ub)
            self._qp.solve()
        if not self._ready or self._qp.results.info.status != Output.PROXQP_SOLVED:
            # Cold start: a warm start from a far-off previous solution can end in a
            # false infeasibility certificate (seen on joint-limits at t = 3.16 s).
            self._qp.init(H, c, A, b, None, None, None, lb, ub)
            self._qp.solve()
            self._ready = True
        status = self._qp.results.info.status
        if status != Output.PROXQP_SOLVED:
            self._fail(str(status).rsplit(".", 1)[-1], status == Output.PROXQP_PRIMAL_INFEASIBLE)
        return np.array(self._qp.results.x)


class QpsolversBackend(QPBackend):
    """Any solver qpsolvers supports (quadprog, proxqp, clarabel, ...), called per step."""

    def __init__(self, nv: int, meq: int, solver: str, **settings):
        super().__init__(nv, meq)
        self.name = solver
        self._settings = settings

    def solve(self, H, c, hessian_changed: bool = True) -> np.ndarray:
        lb = np.maximum(self.lb, -_BIG)
        ub = np.minimum(self.ub, _BIG)
        problem = qpsolvers.Problem(H, c, None, None, self.A if self.meq else None, self.b if self.meq else None, lb, ub)
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
    if native and solver == "proxqp":
        return ProxqpBackend(nv, meq, **settings)
    if solver == "osqp":
        settings = {**OsqpBackend.SETTINGS, **settings}
        settings.pop("warm_starting", None)
    settings = {**_QPSOLVERS_DEFAULTS.get(solver, {}), **settings}
    return QpsolversBackend(nv, meq, solver, **settings)


# Tolerances tight enough for the QP to reproduce the closed-form laws (≤ 1e-6).
_QPSOLVERS_DEFAULTS = {"proxqp": {"eps_abs": 1e-10, "eps_rel": 0.0}}
