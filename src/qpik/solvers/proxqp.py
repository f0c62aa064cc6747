"""ProxQP (proxsuite) through one dense workspace with native box constraints."""

from __future__ import annotations

import numpy as np

from .base import BIG, PROXQP_ITERATIONS, QPBackend, iteration_cap


class ProxqpBackend(QPBackend):
    """One ProxQP dense workspace (box constraints native), updated and warm-started.

    General inequalities are ProxQP's C x ≤ u rows (with l = −BIG). Iterations are capped
    (ProxQP has no time limit): an ill-conditioned problem ends in a typed error instead
    of running for seconds.
    """

    name = "proxqp"

    def __init__(self, nv: int, meq: int, mineq: int = 0, eps_abs: float = 1e-10, eps_rel: float = 0.0,
                 **settings):
        super().__init__(nv, meq, mineq)
        import proxsuite

        self._proxqp = proxsuite.proxqp
        self._qp = proxsuite.proxqp.dense.QP(nv, meq, mineq, True)
        self._qp.settings.eps_abs = eps_abs
        self._qp.settings.eps_rel = eps_rel
        self._qp.settings.max_iter = iteration_cap(PROXQP_ITERATIONS, nv, meq + mineq, cost=40.0)
        self._qp.settings.max_iter_in = PROXQP_ITERATIONS // 10
        self._qp.settings.initial_guess = proxsuite.proxqp.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT
        for key, value in settings.items():
            setattr(self._qp.settings, key, value)
        self._ready = False
        self._lb, self._ub = np.empty(nv), np.empty(nv)
        self._l, self._h = np.full(mineq, -BIG), np.empty(mineq)

    def _solve(self, H, c, hessian_changed: bool) -> np.ndarray:
        lb = np.clip(self.lb, -BIG, BIG, out=self._lb)
        ub = np.clip(self.ub, -BIG, BIG, out=self._ub)
        A, b = self.A, self.b  # (0, nv) and (0,) without equalities
        C, l, u = (self.G, self._l, np.clip(self.h, -BIG, BIG, out=self._h)) if self.mineq else (None, None, None)
        Output = self._proxqp.QPSolverOutput
        if self._ready:
            self._qp.update(H if hessian_changed else None, c, A, b, C, l, u, lb, ub)
            self._qp.solve()
        if not self._ready or self._qp.results.info.status in (Output.PROXQP_PRIMAL_INFEASIBLE,
                                                                Output.PROXQP_DUAL_INFEASIBLE):
            # Cold start: a warm start from a far-off previous solution can end in a
            # false infeasibility certificate (seen on joint-limits at t = 3.16 s). A warm
            # start that ran out of iterations is not restarted: a cold start rescued 6
            # of 32 such solves in the any-robot fuzz, at the cost of a second run to the
            # cap (35 ms on 48 dofs); the guard's exact fallbacks take those steps.
            self._qp.init(H, c, A, b, C, l, u, lb, ub)
            self._qp.solve()
            self._ready = True
        status = self._qp.results.info.status
        if status != Output.PROXQP_SOLVED:
            self._ready = False
            self._fail(str(status).rsplit(".", 1)[-1], status == Output.PROXQP_PRIMAL_INFEASIBLE)
        return np.array(self._qp.results.x)
