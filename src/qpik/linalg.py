"""The few LAPACK calls the control step makes, from SciPy when it is installed, else NumPy.

The closed-form QP step and SNS solve systems of a few rows, where the cost of a call
is its overhead: SciPy's raw LAPACK wrappers (``scipy.linalg.lapack``) are several times
cheaper than ``numpy.linalg`` there, so they are used when SciPy imports (the ``fast``
extra). Without SciPy the same three functions are NumPy implementations with the same
arguments, results and failure reports, so the callers never ask which one they got:

- :func:`dposv` ``(a, b) -> (factor, x, info)``: a x = b for a symmetric positive
  definite ``a`` (its upper triangle read, as LAPACK's default), by Cholesky;
  ``factor``'s diagonal is the Cholesky factor's; ``info > 0`` where ``a`` is not
  positive definite;
- :func:`dgesv` ``(a, b) -> (lu, piv, x, info)``: a x = b by LU with partial pivoting;
  ``lu`` holds U on and above its diagonal (L, unit diagonal, below), ``piv`` the row
  swaps (0-based, as SciPy returns them); ``info > 0`` where U has a zero pivot;
- :func:`dgesvd` ``(a) -> (u, s, vt, info)``: the full SVD (u m×m, vt n×n, s
  descending); ``info > 0`` where it did not converge.

The NumPy path is chosen with ``QPIK_LINALG=numpy`` in the environment (read at import)
or :func:`use`; :data:`BACKEND` says which one is in use. Call these as ``linalg.dposv``
(an attribute looked up at each call), so that :func:`use` reaches every caller.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import InvalidInput
from .extras import installed, require

__all__ = ["BACKEND", "available", "dgesv", "dgesvd", "dposv", "use"]


def _numpy_dposv(a, b, lower=0, overwrite_a=0, overwrite_b=0):
    """LAPACK's dposv with numpy.linalg: the upper triangle (lower=0) or the lower one
    mirrored, so that a slightly asymmetric ``a`` (rounding) reads as LAPACK reads it."""
    a = np.asarray(a, dtype=float)
    triangle = np.tril(a) if lower else np.triu(a)
    symmetric = triangle + triangle.T
    symmetric.reshape(-1)[:: a.shape[0] + 1] = a.diagonal()
    try:
        factor = np.linalg.cholesky(symmetric)
    except np.linalg.LinAlgError:
        return symmetric, np.array(b, dtype=float), 1
    return (factor if lower else factor.T), np.linalg.solve(symmetric, b), 0


def _numpy_dgesv(a, b, overwrite_a=0, overwrite_b=0):
    """LAPACK's dgesv: the LU factors by partial pivoting in NumPy row operations (NumPy
    exposes no LU), x by numpy.linalg.solve (LAPACK's dgesv inside NumPy: the same
    pivoting, so the same x)."""
    lu = np.array(a, dtype=float)
    n = lu.shape[0]
    piv = np.arange(n, dtype=np.int32)
    for k in range(n):
        pivot = k + int(np.abs(lu[k:, k]).argmax())
        piv[k] = pivot
        if pivot != k:
            lu[[k, pivot]] = lu[[pivot, k]]
        if lu[k, k] == 0.0:
            return lu, piv, np.array(b, dtype=float), k + 1
        below = lu[k + 1:, k]
        below /= lu[k, k]
        lu[k + 1:, k + 1:] -= below[:, None] * lu[k, k + 1:]
    return lu, piv, np.linalg.solve(a, b), 0


def _numpy_dgesvd(a, compute_uv=1, full_matrices=1, overwrite_a=0):
    """LAPACK's dgesvd: numpy.linalg.svd, non-convergence (a non-finite ``a``) reported
    as info = 1 with NaN factors instead of an exception."""
    a = np.asarray(a, dtype=float)
    try:
        u, s, vt = np.linalg.svd(a, full_matrices=bool(full_matrices))
    except np.linalg.LinAlgError:
        m, n = a.shape
        k = min(m, n)
        return (np.full((m, m if full_matrices else k), np.nan), np.full(k, np.nan),
                np.full((n if full_matrices else k, n), np.nan), 1)
    return u, s, vt, 0


def available() -> tuple[str, ...]:
    """The back-ends that can be used here: ``("numpy",)`` or ``("scipy", "numpy")``."""
    return ("scipy", "numpy") if installed("scipy") else ("numpy",)


def use(backend: str) -> str:
    """Make ``"scipy"`` (LAPACK's own wrappers) or ``"numpy"`` the implementation of
    :func:`dposv`, :func:`dgesv` and :func:`dgesvd` for every caller; returns the one
    used before (to put it back).

    Raises:
        MissingExtra: ``"scipy"`` where SciPy is not installed.
        InvalidInput: any other name.
    """
    global dposv, dgesv, dgesvd, BACKEND
    previous = globals().get("BACKEND", "numpy")
    if backend == "numpy":
        dposv, dgesv, dgesvd = _numpy_dposv, _numpy_dgesv, _numpy_dgesvd
    elif backend == "scipy":
        require("scipy", "the SciPy linear algebra")
        from scipy.linalg import lapack

        dposv, dgesv, dgesvd = lapack.dposv, lapack.dgesv, lapack.dgesvd
    else:
        raise InvalidInput(f'unknown linear algebra back-end {backend!r}: "scipy" or "numpy"')
    BACKEND = backend
    return previous


dposv = _numpy_dposv
dgesv = _numpy_dgesv
dgesvd = _numpy_dgesvd
BACKEND = "numpy"
_requested = os.environ.get("QPIK_LINALG", "")
if _requested:  # an explicit choice: an error where it cannot be had
    use(_requested)
else:
    try:
        use("scipy")
    except ImportError:  # not installed (MissingExtra), or installed but broken
        pass
