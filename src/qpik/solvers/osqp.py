"""OSQP (ADMM) through one persistent workspace, updated and warm-started each step."""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from .base import BIG, OSQP_ITERATIONS, TIME_LIMIT, QPBackend, iteration_cap


class OsqpBackend(QPBackend):
    """One OSQP workspace, updated in place and warm-started each step.

    The constraint matrix is [A; G; I] with l = [b; −∞; lb], u = [b; h; ub]. Its sparsity
    pattern (dense A and G blocks, identity) and the dense upper triangle of H are fixed
    at setup, so each step only overwrites the numeric values. An update OSQP rejects
    (it would otherwise print an error and solve the previous step's problem again) is a
    :class:`~qpik.errors.SolverError`.
    """

    name = "osqp"
    SETTINGS = dict(eps_abs=1e-8, eps_rel=1e-8, polishing=False, max_iter=OSQP_ITERATIONS, verbose=False,
                    warm_starting=True, adaptive_rho=True, time_limit=TIME_LIMIT)

    def __init__(self, nv: int, meq: int, mineq: int = 0, **settings):
        super().__init__(nv, meq, mineq)
        import osqp
        import scipy.sparse as sp

        self._osqp = osqp
        self._sp = sp
        self._settings = {**self.SETTINGS, "max_iter": iteration_cap(OSQP_ITERATIONS, nv, meq + mineq), **settings}
        rows_p, cols_p = np.triu_indices(nv)
        order = np.lexsort((rows_p, cols_p))  # CSC: column-major, rows sorted
        self._p_rows, self._p_cols = rows_p[order], cols_p[order]
        m = meq + mineq
        dense_r, dense_c = np.meshgrid(np.arange(m), np.arange(nv), indexing="ij")
        a_rows = np.concatenate([dense_r.ravel(), m + np.arange(nv)])
        a_cols = np.concatenate([dense_c.ravel(), np.arange(nv)])
        order = np.lexsort((a_rows, a_cols))
        self._a_rows, self._a_cols = a_rows[order], a_cols[order]
        self._stacked = np.zeros((m + nv, nv))
        self._stacked[m:] = np.eye(nv)
        self._lower, self._upper = np.full(m + nv, -np.inf), np.full(m + nv, np.inf)
        self.A, self.G = self._stacked[:meq], self._stacked[meq:m]
        self.b, self._b_lower = self._upper[:meq], self._lower[:meq]
        self.h = self._upper[meq:m]
        self.lb, self.ub = self._lower[m:], self._upper[m:]
        self._l, self._u = np.empty(m + nv), np.empty(m + nv)
        self._solver = self._workspace = None

    def _solve(self, H, c, hessian_changed: bool) -> np.ndarray:
        self._b_lower[:] = self.b
        p_data = H[self._p_rows, self._p_cols] if hessian_changed or self._solver is None else None
        a_data = self._stacked[self._a_rows, self._a_cols]
        lower = np.clip(self._lower, -BIG, BIG, out=self._l)
        upper = np.clip(self._upper, -BIG, BIG, out=self._u)
        if self._solver is None:
            n, m = self.nv, self.meq + self.mineq + self.nv
            # Explicit zeros are kept: the pattern must not change between updates.
            P = self._pattern(p_data, self._p_rows, self._p_cols, n, n)
            Am = self._pattern(a_data, self._a_rows, self._a_cols, m, n)
            self._solver = self._osqp.OSQP()
            try:
                self._solver.setup(P, c.copy(), Am, lower, upper, **self._settings)
            except Exception as exc:  # OSQP's own exceptions: report, never a traceback
                raise self._error(f"setup rejected the problem: {type(exc).__name__}: {exc}") from None
            # The compiled workspace, when this osqp exposes it: its Python wrapper's
            # update() and solve() add ~20 µs a step (bound clipping through constant
            # lookups, a namespace of every info field) around a ~10 µs solve.
            self._workspace = getattr(self._solver, "_solver", None)
        elif self._workspace is not None:
            flags = (self._workspace.update_data_vec(q=c, l=lower, u=upper),
                     self._workspace.update_data_mat(P_x=p_data, P_i=None, A_x=a_data, A_i=None))
            if any(flags):
                raise self._error(f"OSQP rejected the update (exit flags {flags})")
        else:
            try:
                if p_data is None:
                    self._solver.update(q=c, l=lower, u=upper, Ax=a_data)
                else:
                    self._solver.update(q=c, l=lower, u=upper, Px=p_data, Ax=a_data)
            except Exception as exc:
                raise self._error(f"OSQP rejected the update: {type(exc).__name__}: {exc}") from None
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
        inaccurate_but_feasible = status == Status.OSQP_SOLVED_INACCURATE and info.prim_res <= self._settings["eps_abs"]
        if status != Status.OSQP_SOLVED and not inaccurate_but_feasible:
            infeasible = status in (Status.OSQP_PRIMAL_INFEASIBLE, Status.OSQP_PRIMAL_INFEASIBLE_INACCURATE)
            # The next step must not warm-start from this run's iterates and step size:
            # from them OSQP failed again at every step of an 85-dof dog's level, where a
            # fresh workspace took 75 iterations.
            self._solver = self._workspace = None
            self._fail(str(info.status), infeasible)
        return np.array(x)  # the workspace reuses its solution buffer

    def _error(self, message: str):
        self._solver = self._workspace = None  # set up afresh on the next call
        return SolverError(f"QP solver {self.name}: {message}")

    def _pattern(self, data, rows, cols, m, n):
        """CSC matrix with exactly the given (column-major sorted) entries, zeros kept."""
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.add.at(indptr, cols + 1, 1)
        return self._sp.csc_matrix((data, rows, np.cumsum(indptr)), shape=(m, n))
