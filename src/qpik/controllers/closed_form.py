r"""The equality-constrained QP in closed form: the fast path of a control step.

Most steps of a tracking controller touch no limit. Then the QP's inequalities are
inactive and its solution is that of the equality-constrained problem

.. math::
    \min_x \tfrac12 x^T H x + c^T x \quad\text{s.t.}\quad A x = b,

whose KKT system :math:`Hx + c + A^T\lambda = 0,\ Ax = b` gives, with
:math:`S = A H^{-1} A^T` and :math:`r = b + A H^{-1} c`,

.. math::
    x = H^{-1} A^T S^{-1} r - H^{-1} c .

For a strictly convex QP the minimiser is unique, so if this x also satisfies every
inequality (the box and the general rows), it *is* the QP's solution: the controller
returns it and calls the solver only on steps where a limit would bind. With a constant
Hessian (no soft task with its own Jacobian: the usual hard tasks + posture/damping),
:math:`H^{-1}` is computed once — a vector when H is diagonal.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg.lapack import dgesv, dpotrf, dpotrs  # scipy is loaded with the solvers anyway

# S is treated as singular (the hard rows are dependent) below this relative pivot.
SINGULAR = 1e-12


class ClosedFormStep:
    """Solves min ½xᵀHx + cᵀx s.t. Ax = b; :meth:`solve` returns None where it cannot.

    Args:
        H0: the Hessian when it is the same every step, else None (factorised per call).
        meq: number of equality rows.
    """

    def __init__(self, H0: np.ndarray | None, meq: int):
        self.meq = meq
        self._coefficients = np.full(meq + 1, -1.0)  # [y; −1], y written per step
        self._dinv = self._Hinv = None
        if H0 is not None:
            diagonal = np.diag(H0)
            if np.count_nonzero(H0 - np.diag(diagonal)) == 0 and np.all(diagonal > 0):
                self._dinv = 1.0 / diagonal
            else:
                try:
                    np.linalg.cholesky(H0)
                except np.linalg.LinAlgError:
                    self._Hinv = None
                else:
                    self._Hinv = np.linalg.inv(H0)
        self.constant = H0 is not None and (self._dinv is not None or self._Hinv is not None)

    def solve(self, H: np.ndarray, Ac: np.ndarray, b: np.ndarray) -> np.ndarray | None:
        """x of the KKT system, or None (H not positive definite, S singular).

        ``Ac`` stacks the equality rows A (meq x nv) and the cost vector cᵀ as its last row:
        with a constant diagonal H one product (A H⁻¹ or c H⁻¹ rows) @ [Aᵀ c] gives both
        S = A H⁻¹ Aᵀ and A H⁻¹ c.
        """
        meq = self.meq
        if self._dinv is not None:
            scaled = Ac * self._dinv  # rows: A H⁻¹, cᵀ H⁻¹
            if not meq:
                return -scaled[0]
            M = scaled @ Ac.T
            if meq <= 2:  # S y = r in floats
                rows, rhs = M.tolist(), b.tolist()
                if meq == 1:
                    s = rows[0][0]
                    if not s > SINGULAR:
                        return None
                    coefficients = ((rows[0][1] + rhs[0]) / s, -1.0)
                else:
                    (a, b_, r0), (_, d, r1) = rows[0], rows[1]
                    r0 += rhs[0]
                    r1 += rhs[1]
                    det = a * d - b_ * b_
                    if not det > SINGULAR * max(a * d, 1e-300):
                        return None
                    coefficients = ((d * r0 - b_ * r1) / det, (a * r1 - b_ * r0) / det, -1.0)
                # x = H⁻¹Aᵀ y − H⁻¹c = [A H⁻¹; cᵀH⁻¹]ᵀ [y; −1]
                return scaled.T @ np.array(coefficients)
            y = _solve_small(M[:meq, :meq], M[:meq, meq] + b)
            if y is None:
                return None
            coefficients = self._coefficients
            coefficients[:meq] = y
            return scaled.T @ coefficients
        A, c = Ac[:meq], Ac[meq]
        if self._Hinv is not None:
            Hinv = self._Hinv
            Hinv_c = Hinv @ c
            HinvAT = Hinv @ A.T if meq else None
        else:
            Y = _cholesky_solve(H, Ac.T)
            if Y is None:
                return None
            HinvAT, Hinv_c = Y[:, :meq], Y[:, meq]
        if not meq:
            return -Hinv_c
        y = _solve_small(A @ HinvAT, A @ Hinv_c + b)
        if y is None:
            return None
        x = HinvAT @ y
        x -= Hinv_c
        return x


def _cholesky_solve(H: np.ndarray, rhs: np.ndarray) -> np.ndarray | None:
    """H⁻¹ rhs by Cholesky (LAPACK ``potrf`` + ``potrs``), or None if H is not positive definite.

    The algorithm of ``numpy.linalg.cholesky`` followed by two
    ``scipy.linalg.solve_triangular``, called directly: those layers cost ~20 µs a step
    (6 x 6: 2 µs here instead of 24), and ``solve_triangular``'s transposed solve is a path
    OpenBLAS runs multithreaded, which took milliseconds instead of ~15 µs on a loaded
    two-core machine (the humanoid's 62 x 62). Results agree to rounding (another LAPACK
    build: 9e-16 rad on the Jaco circle's joints).
    """
    factor, info = dpotrf(H, lower=True, clean=False)  # H symmetric: only its lower triangle is read
    if info != 0:
        return None
    solution, info = dpotrs(factor, rhs, lower=True)
    return solution if info == 0 else None


def _solve_small(S: np.ndarray, r: np.ndarray) -> np.ndarray | None:
    """S⁻¹ r for the symmetric positive (semi)definite S = A H⁻¹ Aᵀ; None if singular.

    One and two rows in Python floats (a LAPACK call costs more than the arithmetic)."""
    m = len(r)
    if m == 1:
        s = float(S[0, 0])
        return None if not s > SINGULAR else r / s
    if m == 2:
        (a, b_), (_, d) = S.tolist()
        det = a * d - b_ * b_
        if not det > SINGULAR * max(a * d, 1e-300):
            return None
        r0, r1 = r.tolist()
        return np.array(((d * r0 - b_ * r1) / det, (a * r1 - b_ * r0) / det))
    # LU with partial pivoting, numpy.linalg.solve's LAPACK routine without its ~4 µs of
    # Python; info > 0: an exactly zero pivot (singular S).
    _, _, y, info = dgesv(S, r)
    if info != 0:
        return None
    # A nearly singular S (dependent hard rows) gives a y that misses S y = r: refuse it.
    # (In floats: for a dozen rows cheaper than three NumPy reductions; NaN fails too.)
    targets = r.tolist()
    tolerance = 1e-9 * (1.0 + max(abs(target) for target in targets))
    for value, target in zip((S @ y).tolist(), targets):
        if not abs(value - target) <= tolerance:
            return None
    return y
