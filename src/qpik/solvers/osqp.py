"""OSQP (ADMM) through one persistent workspace, updated and warm-started each step."""

from __future__ import annotations

import numpy as np

from .base import BIG, QPBackend


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
        lower = np.maximum(self._lower, -BIG)
        upper = np.minimum(self._upper, BIG)
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
