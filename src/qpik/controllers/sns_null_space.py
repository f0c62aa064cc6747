"""SNS's linear algebra on one world's arrays: the rank-revealing pseudoinverse of a
task's rows (:func:`pseudoinverse`) and the null space the levels done leave
(:class:`NullSpace`), carried as an orthonormal basis Z or as the projector P = Z Zᵀ.

These run inside SNS's per-world passes (:mod:`qpik.controllers.sns`) on views of
the (N, ...) arrays: the saturation passes are data-dependent per world. Products use
``ndarray.dot``: ``@`` costs twice as much at these sizes.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dgesvd

from ..errors import DivergenceError

RANK_TOLERANCE = 1e-10  # singular values below this fraction of the largest count as zero


def pseudoinverse(X: np.ndarray, scale: float | None,
                  tolerance: float = RANK_TOLERANCE) -> tuple[np.ndarray, int, np.ndarray | None]:
    """(X⁺, X's rank, the Vᵀ of its SVD or None when none was made). Singular values below
    ``tolerance · scale`` count as zero (``scale`` the size of J itself, X being J Z or
    J P: a direction the levels above nearly took is kept; None: X's largest). One row:
    xᵀ/‖x‖²; more: one SVD from LAPACK directly (NumPy's wrapper costs more than the
    decomposition at these sizes).

    Raises:
        DivergenceError: X is not finite.
    """
    if X.shape[0] == 1:  # one row x: x^# = xᵀ/‖x‖²
        row = X[0]
        norm_sq = float(row.dot(row))
        if not math.isfinite(norm_sq):
            raise DivergenceError("SNS: a task Jacobian is not finite")
        rank = 1 if norm_sq > (tolerance * (math.sqrt(norm_sq) if scale is None else scale)) ** 2 else 0
        return (X.T / norm_sq if rank else 0.0 * X.T), rank, None
    u, s, vt, info = dgesvd(X)
    largest = float(s[0])
    if info != 0 or not math.isfinite(largest):
        raise DivergenceError("SNS: the singular value decomposition failed (non-finite Jacobian)")
    threshold = tolerance * (largest if scale is None else scale)
    rank = len(s) if s[-1] > threshold else int(np.count_nonzero(s > threshold))
    if rank == len(s) == X.shape[0]:  # full row rank, the usual case
        return vt[:rank].T.dot(u.T / s[:, None]), rank, vt
    return vt[:rank].T.dot(u[:, :rank].T / s[:rank, None]), rank, vt


class NullSpace:
    """The null space of the levels done, of dimension ``free``: all of joint space
    (``F`` None), an orthonormal basis Z (``F``), or, ``projector``, P = Z Zᵀ itself."""

    def __init__(self, nv: int):
        self.F, self.projector, self.free = None, False, nv

    def mapped(self, pinv: np.ndarray) -> np.ndarray:
        """(J Z)^# mapped back to joint space (Z (J Z)^#); as it is in joint space or a projector's."""
        return pinv if self.F is None or self.projector else self.F.dot(pinv)

    def hold(self, critical: int, target: float, shifted: np.ndarray, rows: np.ndarray, held: list):
        """Joint ``critical`` held at ``target`` (``held``: the directions held before, appended
        to): (q̇ shifted, the task's rows less that direction), or None where it cannot be."""
        if self.projector:
            return self._hold_in_projector(critical, target, shifted, rows, held)
        # Within the basis, as close as it allows: along h, the joint's row of Z less its
        # part along the joints already held.
        F = self.F
        h = F[critical]
        for u in held:
            h = h - u.dot(h) * u
        norm_sq = float(h.dot(h))
        if norm_sq <= RANK_TOLERANCE**2:
            return None
        shifted = shifted + F.dot(h * ((target - shifted[critical]) / norm_sq))
        u = h / math.sqrt(norm_sq)
        held.append(u)
        return shifted, rows - rows.dot(u)[:, None] * u  # J Z (I − u uᵀ): the task without u

    def _hold_in_projector(self, critical: int, target: float, shifted: np.ndarray, rows: np.ndarray, held: list):
        """:meth:`hold` along d = P̄ e_i, P̄ = P less the joints already held."""
        d = self.F[critical]
        for e, norm in held:
            d = d - e * (e[critical] / norm)
        norm_sq = float(d[critical])  # ‖P̄ e_i‖²
        if norm_sq <= RANK_TOLERANCE**2:
            return None
        shifted = shifted + d.dot((target - shifted.item(critical)) / norm_sq)  # dot: a faster *
        held.append((d, norm_sq))
        # J P̄: the task without d
        return shifted, rows - (d.dot(rows.dot(d).item() / norm_sq) if len(rows) == 1 else
                                (rows.dot(d) / norm_sq)[:, None] * d)

    def reduce(self, rank: int, pinv: np.ndarray, X: np.ndarray, vt: np.ndarray | None, eye: np.ndarray) -> None:
        """The null space left after a level of this ``rank`` (X = J F its rows, ``pinv``
        their pseudoinverse, ``vt`` their SVD's Vᵀ or None)."""
        self.free -= rank
        if self.projector or (self.F is None and vt is None):  # P_k = P_{k-1} − X⁺X, X = J P_{k-1}
            self.F, self.projector = (eye if self.F is None else self.F) - pinv.dot(X), True
            return
        if vt is None:  # one row in a basis: decompose now
            vt = dgesvd(X)[2]
        null = vt[rank:].T
        self.F = null if self.F is None else self.F.dot(null)
