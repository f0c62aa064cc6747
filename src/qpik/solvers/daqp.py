"""DAQP, a dual active-set solver for dense problems, through its own interface."""

from __future__ import annotations

from ctypes import c_int

import numpy as np

from .base import QPBackend


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
