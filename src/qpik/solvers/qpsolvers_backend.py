"""Any other solver that qpsolvers knows, called through ``qpsolvers.solve_problem``."""

from __future__ import annotations

import numpy as np
import qpsolvers
from scipy.sparse import csc_matrix

from .base import BIG, EXACT_EQUALITY_TOLERANCE, QPBackend


# Active-set solvers among qpsolvers' (their active constraints hold to machine precision).
EXACT_SOLVERS = ("quadprog", "daqp", "qpoases")


class QpsolversBackend(QPBackend):
    """Any solver qpsolvers supports (quadprog, proxqp, clarabel, ...), called per step."""

    def __init__(self, nv: int, meq: int, mineq: int = 0, *, solver: str, **settings):
        super().__init__(nv, meq, mineq)
        self.name = solver
        self.exact = solver in EXACT_SOLVERS
        if self.exact:
            self.equality_tolerance = EXACT_EQUALITY_TOLERANCE
        self._settings = settings
        # A solver that takes sparse matrices only gets them so (qpsolvers would convert
        # them itself, with a SparseConversionWarning every step).
        self._sparse = solver not in qpsolvers.dense_solvers

    def _solve(self, H, c, hessian_changed: bool) -> np.ndarray:
        lb = np.clip(self.lb, -BIG, BIG)
        ub = np.clip(self.ub, -BIG, BIG)
        G, h = (self.G, np.clip(self.h, -BIG, BIG)) if self.mineq else (None, None)
        A, b = (self.A, self.b) if self.meq else (None, None)
        if self._sparse:
            H, G, A = (None if m is None else csc_matrix(m) for m in (H, G, A))
        problem = qpsolvers.Problem(H, c, G, h, A, b, lb, ub)
        try:
            solution = qpsolvers.solve_problem(problem, solver=self.name, **self._settings)
        except Exception as exc:  # solver-specific exceptions: report, don't traceback
            self._fail(f"{type(exc).__name__}: {exc}", "infeasible" in str(exc).lower())
        if not solution.found or solution.x is None:
            self._fail("no solution found (infeasible constraints or solver failure)", False)
        return solution.x
