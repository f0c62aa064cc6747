r"""The QP with its equality rows eliminated first, then solved by DAQP: the exact fallback
for hard rows whose scales the dual solvers cannot resolve.

DAQP and quadprog are dual active-set methods: each iteration factors
:math:`C H^{-1} C^T` over the active rows C (hard rows and bounds alike), whose condition
number is the square of the rows' times H's. On a robot stretched a million metres (a
one-sided range at ±1e6 m, or a hard target 1e8 m away a few steps earlier) a hard row
holds entries of 1e6 beside entries of 1e-2: once the dof carrying the large entry is at
its bound, what is left of the row is 1e-8 of its norm and its pivot 1e-16 of the others,
below those solvers' singularity tolerance, and they report a feasible step infeasible
(their phase-1 problem too). Scaling rows and columns does not remove it: the product
is invariant under a change of the variables' units.

Here A x = b is solved once by an SVD (backward stable, no squaring): every point of it
is :math:`x = x_p + N z`, :math:`x_p` the least-squares solution and N an orthonormal basis
of A's null space. What is left has no equality,

.. math::
    \min_z \tfrac12 z^T (N^T H N) z + (N^T (H x_p + c))^T z
    \quad\text{s.t.}\quad lb \le x_p + N z \le ub,\quad G (x_p + N z) \le h,

with each row scaled to unit norm, and DAQP solves it with rows as well conditioned as H.
Its answer :math:`x_p + N z` goes through the checks every back-end's answer goes through
(:class:`~qpik.solvers.base.QPBackend`).
"""

from __future__ import annotations

import numpy as np

from .base import BIG
from .daqp import DaqpBackend

EPS = float(np.finfo(float).eps)
# A row of N (a dof's share of the null space) shorter than this is a dof the hard rows
# fix on their own: its bound is then a constant, checked rather than passed on.
FIXED_DOF_ROW = 64 * EPS


class NullSpaceBackend(DaqpBackend):
    """DAQP on the QP reduced to the null space of its equality rows (see the module).

    Its answer is exact as DAQP's is: x_p meets the rows to rounding, N z adds nothing to
    them, and an active bound holds to the rounding of forming x_p + N z, which
    ``bound_tolerance`` allows (set per solve, relative to those vectors' size) before the
    answer is projected onto the box.
    """

    # DAQP's settings and tolerances; bound_tolerance is widened per solve by the rounding of x_p + N z.
    name = "daqp (null space of the hard rows)"

    def _solve(self, H, c, hessian_changed: bool) -> np.ndarray:
        particular, basis = self._null_space()
        self._allow_rounding(particular)
        rows, bounds = self._reduced_rows(particular, basis)
        z = self._reduced_minimiser(H, c, particular, basis, rows, bounds)
        step = basis @ z
        self._allow_rounding(particular, step)
        return particular + step

    def _allow_rounding(self, *parts: np.ndarray) -> None:
        """``bound_tolerance`` widened by the rounding of a sum of ``parts`` (nv terms each)."""
        magnitude = sum(float(np.abs(part).max(initial=0.0)) for part in parts)
        self.bound_tolerance = type(self).bound_tolerance + 16 * self.nv * EPS * magnitude

    def _null_space(self) -> tuple[np.ndarray, np.ndarray]:
        """x_p (the least-squares solution of A x = b) and N (nv × (nv − rank))."""
        u, s, vt = np.linalg.svd(self.A, full_matrices=True)
        rank = int(np.count_nonzero(s > max(self.A.shape) * EPS * s[0])) if s.size and s[0] > 0 else 0
        particular = vt[:rank].T @ ((u[:, :rank].T @ self.b) / s[:rank])
        return particular, vt[rank:].T

    def _reduced_rows(self, particular: np.ndarray, basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The box and the general rows as rows R z <= r, each of unit norm."""
        upper, lower = np.isfinite(self.ub), np.isfinite(self.lb)
        finite = self.h < BIG
        rows = np.vstack([basis[upper], -basis[lower], self.G[finite] @ basis])
        bounds = np.concatenate([self.ub[upper] - particular[upper], particular[lower] - self.lb[lower],
                                 self.h[finite] - self.G[finite] @ particular])
        norms = np.linalg.norm(rows, axis=1) if basis.shape[1] else np.zeros(len(bounds))
        fixed = norms <= FIXED_DOF_ROW
        if (bounds[fixed] < -self.bound_tolerance).any():  # a dof the hard rows put outside its box
            self._fail("the hard rows fix a dof outside its bounds", True)
        keep = ~fixed
        return rows[keep] / norms[keep, None], bounds[keep] / norms[keep]

    def _reduced_minimiser(self, H, c, particular, basis, rows, bounds) -> np.ndarray:
        free = basis.shape[1]
        if free == 0:
            return np.zeros(0)
        reduced = basis.T @ H @ basis
        reduced = 0.5 * (reduced + reduced.T)
        gradient = basis.T @ (H @ particular + c)
        z, _, exitflag, _ = self._solve_daqp(reduced, gradient, np.ascontiguousarray(rows), bounds,
                                             np.full(len(bounds), -np.inf), np.zeros(len(bounds), dtype=np.intc),
                                             **self._settings)
        if exitflag < 1:
            self._fail(f"exit flag {exitflag}", exitflag == -1)
        return z
