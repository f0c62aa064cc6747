"""The batched small linear algebra (qpik.batch.linalg, the QP's S solve) against LAPACK."""

import numpy as np
import pytest

from qpik.batch.linalg import cholesky_solve
from qpik.batch.qp import spd_solve


@pytest.mark.parametrize("n, m", [(1, 1), (2, 3), (7, 1), (24, 2)])
def test_cholesky_solve_equals_lapack(n, m):
    rng = np.random.default_rng(n + m)
    J = rng.normal(size=(50, n + 2, n))
    M = J.transpose(0, 2, 1) @ J + 1e-3 * np.eye(n)
    B = rng.normal(size=(50, n, m))
    X, pivots = cholesky_solve(M, B)
    expected = np.linalg.solve(M, B)
    scale = 1.0 + np.abs(expected).max()
    np.testing.assert_allclose(X, expected, rtol=0, atol=1e-10 * scale)
    # The pivots, norm-wise per matrix: a Cholesky factor is backward stable, each pivot
    # off by about n ε |M| / pivot; 1e3 n ε κ(M) |pivots| bounds that on every kernel.
    reference = np.diagonal(np.linalg.cholesky(M), axis1=1, axis2=2)
    bound = 1e3 * n * np.finfo(float).eps * np.linalg.cond(M) * np.linalg.norm(reference, axis=1)
    assert np.all(np.linalg.norm(pivots - reference, axis=1) <= bound)


def test_cholesky_solve_flags_matrices_that_are_not_positive_definite():
    M = np.stack([np.eye(3), np.diag([1.0, -1.0, 1.0]), np.zeros((3, 3))])
    X, pivots = cholesky_solve(M, np.ones((3, 3, 1)))
    assert (pivots[0] > 0).all()
    assert not (pivots[1] > 0).all() and not (pivots[2] > 0).all()
    np.testing.assert_array_equal(X[0], np.ones((3, 1)))


@pytest.mark.parametrize("m", [1, 2, 3, 5])
def test_spd_solve_equals_lapack_and_refuses_what_the_serial_closed_form_refuses(m):
    rng = np.random.default_rng(m)
    A = rng.normal(size=(40, m, m + 2))
    S = A @ A.transpose(0, 2, 1)
    r = rng.normal(size=(40, m))
    singular = A[:5].copy()
    singular[:, -1] = singular[:, 0] * (1.0 + 1e-14)  # dependent rows: cond(S) far past 1e12
    S[:5] = singular @ singular.transpose(0, 2, 1)
    S[5] = -np.eye(m)  # not positive definite
    y, ok = spd_solve(S, r)
    if m == 1:  # one row: only a non-positive S is refused
        assert ok[:5].all() and not ok[5]
    else:
        assert not ok[:6].any()
    assert ok[6:].all()
    np.testing.assert_allclose(y[6:], np.linalg.solve(S[6:], r[6:, :, None])[:, :, 0], rtol=0, atol=1e-9)
