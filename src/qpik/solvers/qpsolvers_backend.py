"""Any other solver that qpsolvers knows, called through ``qpsolvers.solve_problem``."""

from __future__ import annotations

import numpy as np
import qpsolvers

from ..errors import SolverError
from .base import BIG, QPBackend


class QpsolversBackend(QPBackend):
    """Any solver qpsolvers supports (quadprog, proxqp, clarabel, ...), called per step."""

    def __init__(self, nv: int, meq: int, solver: str, **settings):
        super().__init__(nv, meq)
        self.name = solver
        self._settings = settings

    def solve(self, H, c, hessian_changed: bool = True) -> np.ndarray:
        lb = np.maximum(self.lb, -BIG)
        ub = np.minimum(self.ub, BIG)
        problem = qpsolvers.Problem(H, c, None, None, self.A if self.meq else None, self.b if self.meq else None, lb, ub)
        try:
            solution = qpsolvers.solve_problem(problem, solver=self.name, **self._settings)
        except Exception as exc:  # solver-specific exceptions: report, don't traceback
            raise SolverError(f"QP solver {self.name} failed: {type(exc).__name__}: {exc}") from None
        if not solution.found or solution.x is None:
            self._fail("no solution found (infeasible constraints or solver failure)", False)
        return solution.x
