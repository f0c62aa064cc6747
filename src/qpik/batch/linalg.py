"""Small dense linear algebra over many worlds at once, in NumPy.

NumPy's stacked routines (``np.linalg.solve`` and ``matmul`` on (N, n, n) arrays) call
LAPACK or an inner loop once per matrix: for the few unknowns of a control step that
per-matrix overhead is most of their cost. The functions here put the world axis last,
so that each arithmetic operation is one vector operation over every world.
"""

from __future__ import annotations

import numpy as np


def worlds_last(a: np.ndarray) -> np.ndarray:
    """(N, ...) -> (..., N), contiguous."""
    return np.ascontiguousarray(np.moveaxis(a, 0, -1))


def cholesky_solve(M: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Solve M_k X_k = B_k for every world k, each M_k symmetric positive definite, by
    Cholesky's factorisation M_k = L_k L_kᵀ (only the lower triangle of M_k is read).

    Args:
        M: (N, n, n).
        B: (N, n, m).

    Returns:
        ``(X (N, n, m), pivots (N, n))``: the pivots are the diagonal of L; a world
        whose matrix is not numerically positive definite has a pivot that is not > 0
        (zero where the square root would be of a number <= 0), and its X means nothing.
    """
    X, pivots = cholesky_solve_last(worlds_last(M), worlds_last(B))
    return np.moveaxis(X, -1, 0), pivots.T


def cholesky_solve_last(Mt: np.ndarray, Bt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cholesky_solve` with the worlds along the last axis: Mt (n, n, N),
    Bt (n, m, N); returns X (n, m, N) and the pivots (n, N)."""
    n = Mt.shape[0]
    L = np.zeros_like(Mt)
    pivots = np.empty((n, Mt.shape[2]))
    for j in range(n):
        d = Mt[j, j] - (L[j, :j] * L[j, :j]).sum(axis=0) if j else Mt[j, j]
        positive = d > 0.0
        root = np.sqrt(np.where(positive, d, 1.0))
        pivots[j] = np.where(positive, root, 0.0)
        L[j, j] = root
        if j + 1 < n:
            column = Mt[j + 1:, j] - (L[j + 1:, :j] * L[j, :j]).sum(axis=1) if j else Mt[j + 1:, j]
            L[j + 1:, j] = column / root
    Y = np.empty_like(Bt)
    for j in range(n):  # L Y = B
        rest = Bt[j] - (L[j, :j, None] * Y[:j]).sum(axis=0) if j else Bt[j]
        Y[j] = rest / L[j, j]
    X = Y  # Lᵀ X = Y, in place from the last row up
    for j in range(n - 1, -1, -1):
        if j < n - 1:
            X[j] = (Y[j] - (L[j + 1:, j, None] * X[j + 1:]).sum(axis=0)) / L[j, j]
        else:
            X[j] = Y[j] / L[j, j]
    return X, pivots
