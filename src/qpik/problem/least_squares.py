r"""The equality-constrained least-squares step in damped least-squares form, in every world.

.. math::
    \min_x\ \tfrac12 \|R_1 x - r_1\|^2 + \tfrac12 x^T D x + c^T x
    \quad\text{s.t.}\quad R_2 x = r_2

(:math:`R_1` the first ``soft_rows`` rows of R, D a positive diagonal). Written through
the rows rather than the Hessian :math:`R_1^TR_1 + D`:

.. math::
    x = D^{-1}(R^T z - c),\qquad
    \big(R D^{-1} R^T + \mathrm{diag}(I, 0)\big)\, z = r + R D^{-1} c

which keeps its digits where D is only a tiny ε on the joints the rows leave free (H⁻¹
would be of order 1/ε). A level of the hierarchy with soft tasks of their own Jacobian
is solved so (:class:`~qpik.controllers.hierarchy.HierarchicalController`); its
solver's answers are polished by the same step with the active bounds held: a held dof
has :math:`D^{-1} = 0` there (x is 0 on it, its bound's value added after), so one
shape serves every active set.
"""

from __future__ import annotations

import numpy as np

from ..numerics import all_finite, both, cholesky_solve, everywhere
from .closed_form import EQUALITY_TOLERANCE, SINGULAR_RATIO, rows_met


class DampedLeastSquares:
    """The step above in ``n`` worlds of ``nv`` dofs, ``soft_rows`` rows R₁ and ``rows``
    rows R₂ (the equalities), with its buffers (allocated once)."""

    def __init__(self, n: int, nv: int, soft_rows: int, rows: int):
        m = soft_rows + rows
        self.soft_rows, self.rows = soft_rows, rows
        self.scaled, self.K = np.empty((n, m, nv)), np.empty((n, m, m))  # R D⁻¹, R D⁻¹ Rᵀ + diag(I, 0)
        self._soft_diagonal = np.einsum("nii->ni", self.K)[:, :soft_rows]  # a writable view
        self.right, self._Dc = np.empty((n, m)), np.empty((n, m, 1))  # r + R D⁻¹ c, R D⁻¹ c
        self.x = np.empty((n, nv))
        self._x_row, self._x_column = self.x[:, None, :], self.x[:, :, None]
        self._met = np.empty((n, rows, 1))  # R₂ x

    def solve(self, dinv: np.ndarray, R: np.ndarray, rhs: np.ndarray, c: np.ndarray | None = None):
        """``(x (N, nv), ok (N,))``: ``ok`` where the system is numerically positive
        definite (its Cholesky pivots span at most ``SINGULAR_RATIO``), x is finite and
        meets R₂x = r₂ to ``EQUALITY_TOLERANCE`` relative; x means nothing elsewhere (a
        buffer, overwritten by the next solve).

        Args:
            dinv: (N, nv) D⁻¹ (0 on a held dof).
            R: (N, soft_rows + rows, nv) [R₁; R₂].
            rhs: (N, soft_rows + rows) [r₁; r₂].
            c: (N, nv), or None for zero.
        """
        scaled, K, x = self.scaled, self.K, self.x
        np.multiply(R, dinv[:, None, :], scaled)
        np.matmul(scaled, R.transpose(0, 2, 1), K)
        self._soft_diagonal += 1.0
        right = rhs
        if c is not None:
            np.matmul(scaled, c[:, :, None], self._Dc)
            right = np.add(rhs, self._Dc[:, :, 0], self.right)
        z, solved = cholesky_solve(K, right, SINGULAR_RATIO)
        np.matmul(z[:, None, :], R, self._x_row)
        if c is not None:
            x -= c
        x *= dinv
        finite = everywhere(len(x)) if all_finite(x) else np.isfinite(x).all(axis=1)
        if not self.rows:
            return x, both(solved, finite)
        np.matmul(R[:, self.soft_rows:], self._x_column, self._met)
        return x, both(solved, finite, rows_met(self._met[:, :, 0], rhs[:, self.soft_rows:], EQUALITY_TOLERANCE))

    def cost(self, x: np.ndarray, dinv: np.ndarray, R: np.ndarray, rhs: np.ndarray, c: np.ndarray | None) -> np.ndarray:
        r""":math:`\tfrac12 \|R_1 x - r_1\|^2 + \tfrac12 x^T D x + c^T x` of x (N, nv) in
        every world (N,), ``dinv`` > 0 everywhere (D itself)."""
        m = self.soft_rows
        residual = np.einsum("nij,nj->ni", R[:, :m], x) - rhs[:, :m]
        value = 0.5 * np.einsum("ni,ni->n", residual, residual) + 0.5 * np.einsum("ni,ni->n", x, x / dinv)
        return value if c is None else value + np.einsum("ni,ni->n", c, x)
