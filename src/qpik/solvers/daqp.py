"""DAQP, a dual active-set solver for dense problems, through its own interface."""

from __future__ import annotations

from ctypes import c_int

import numpy as np

from .base import EXACT_EQUALITY_TOLERANCE, TIME_LIMIT, QPBackend, active_set_iterations


class DaqpBackend(QPBackend):
    """DAQP (dual active set, dense): bounds as simple bounds, equalities by ``sense``.

    DAQP takes one constraint matrix [A; G] and the bound vectors
    lower = [lb; b; −inf], upper = [ub; b; h]; ``lb``, ``ub``, ``b``, ``h``, ``A``, ``G``
    are views into them.
    """

    name = "daqp"
    exact = True  # active set: an active bound holds exactly
    bound_tolerance = 1e-5
    equality_tolerance = EXACT_EQUALITY_TOLERANCE
    _EXIT = {-1: "primal infeasible", -2: "cycling detected", -3: "unbounded problem",
             -4: "iteration limit reached", -5: "nonconvex problem", -6: "overdetermined initial active set",
             -7: "time limit reached"}

    def __init__(self, nv: int, meq: int, mineq: int = 0, **settings):
        super().__init__(nv, meq, mineq)
        import daqp

        self._solve_daqp = daqp.solve
        self._settings = {"iter_limit": active_set_iterations(nv, meq + mineq), "time_limit": TIME_LIMIT,
                          **settings}
        m = meq + mineq
        self._constraints = np.zeros((m, nv))
        self.A, self.G = self._constraints[:meq], self._constraints[meq:]
        self._upper = np.full(nv + m, np.inf)
        self._lower = np.full(nv + m, -np.inf)
        self.lb, self.ub = self._lower[:nv], self._upper[:nv]
        self.b, self._b_lower = self._upper[nv:nv + meq], self._lower[nv:nv + meq]
        self.h = self._upper[nv + meq:]
        self._sense = np.zeros(nv + m, dtype=c_int)
        self._sense[nv:nv + meq] = 5  # equality rows

    def _solve(self, H, c, hessian_changed: bool) -> np.ndarray:
        self._b_lower[:] = self.b
        x, _, exitflag, _ = self._solve_daqp(H, c, self._constraints, self._upper, self._lower, self._sense,
                                             **self._settings)
        if exitflag < 1:
            self._fail(self._EXIT.get(exitflag, f"exit flag {exitflag}"), exitflag == -1)
        return x
