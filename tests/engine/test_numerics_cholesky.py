"""engine.numerics.cholesky_factor and cholesky_substitute: every world's answer equals
LAPACK's (NumPy's solve) at N = 1 (MuJoCo's factor and solve; LAPACK's potrs on MuJoCo's
factor for several right sides) and N > 1 (the worlds-last path), a factor serves further
right sides (a refinement's), and the flags say which worlds factored — the shared
:func:`~qpik.numerics.everywhere` when all did, so that a caller's fast path
(``solved is everywhere(n)``) is taken on the usual step."""

import numpy as np
import pytest

from qpik.numerics import cholesky_factor, cholesky_substitute, everywhere

# Well-conditioned SPD systems of entries ~1 (cond < 1e3): the two solves agree to a few
# hundred roundings.
ROUNDING = 1e-12


def cholesky_solve(M, B, ratio=np.inf):
    """The engine's solve: the factor, then its substitution (refused worlds zero)."""
    factor, ok = cholesky_factor(M, ratio)
    return cholesky_substitute(factor, B, ok), ok


def _systems(n: int, k: int, seed: int):
    rng = np.random.default_rng(seed)
    L = rng.normal(size=(n, k, k))
    M = L @ L.transpose(0, 2, 1) + k * np.eye(k)
    return M, rng.normal(size=(n, k)), rng.normal(size=(n, k, 3))


@pytest.mark.parametrize("n, k", [(1, 2), (1, 7), (5, 1), (64, 2), (64, 7)])
def test_cholesky_solve_equals_lapack_in_every_world(n, k):
    M, b, B = _systems(n, k, seed=n + k)
    for rhs in (b, B):
        X, ok = cholesky_solve(M, rhs)
        assert ok is everywhere(n)
        expected = np.linalg.solve(M, rhs[..., None])[..., 0] if rhs.ndim == 2 else np.linalg.solve(M, rhs)
        np.testing.assert_allclose(X, expected, rtol=0, atol=ROUNDING)


@pytest.mark.parametrize("n", [1, 6])
def test_worlds_not_positive_definite_or_too_ill_conditioned_are_flagged(n):
    M, b, _ = _systems(n, 3, seed=2)
    M[-1] = -np.eye(3)  # not positive definite
    _, ok = cholesky_solve(M, b)
    assert ok is not everywhere(n) and ok.tolist() == [True] * (n - 1) + [False]
    M[-1] = np.diag([1.0, 1e-20, 1e20])  # orthogonal rows of any scales: solved
    _, ok = cholesky_solve(M, b, ratio=1e6)
    assert ok is everywhere(n)
    delta = 1e-14  # rows 0 and 1 at an angle of about √(2δ) = 1.4e-7: √M₁₁ / L₁₁ = 7e6 > the ratio asked
    M[-1] = [[1.0, 1.0 - delta, 0.0], [1.0 - delta, 1.0, 0.0], [0.0, 0.0, 1.0]]
    _, ok = cholesky_solve(M, b, ratio=1e6)
    assert ok.tolist() == [True] * (n - 1) + [False]


def _conditioned(rng, k: int, condition: float) -> np.ndarray:
    """A symmetric positive definite k x k matrix whose condition number is ``condition``."""
    q, _ = np.linalg.qr(rng.normal(size=(k, k)))
    M = (q * np.geomspace(1.0, 1.0 / condition, k)) @ q.T
    return 0.5 * (M + M.T)


@pytest.mark.parametrize("n", [1, 6])
@pytest.mark.parametrize("k", [2, 4, 7, 30])
@pytest.mark.parametrize("condition", [1.0, 1e4, 1e8, 1e11])
def test_ill_conditioned_solves_agree_with_lapack_to_their_condition(n, k, condition):
    """Both paths are backward-stable solves of the same system: each world's answer and
    LAPACK's (NumPy's LU) differ by the rounding of such a solve amplified by κ, at most
    64 ε κ relative (measured: 2.6 ε κ at most, κ up to 1e11, 30 x 30)."""
    rng = np.random.default_rng(int(k + np.log10(condition) + 100 * n))
    M = np.stack([_conditioned(rng, k, condition) for _ in range(n)])
    B = rng.normal(size=(n, k))
    X, ok = cholesky_solve(M, B)
    assert np.asarray(ok).all()
    for w in range(n):
        expected = np.linalg.solve(M[w], B[w])
        bound = 64 * np.finfo(float).eps * np.linalg.cond(M[w]) * np.abs(expected).max()
        assert np.abs(X[w] - expected).max() <= bound


@pytest.mark.parametrize("n", [1, 5])
def test_the_ratio_is_lapacks_factor_against_the_diagonal(n):
    """``ratio`` refuses a world whose Cholesky pivots fall below √M_jj / ratio: the largest
    √M_jj / L_jj of LAPACK's factor (NumPy's cholesky), a hair above it solved, a hair below
    it refused, on both paths."""
    rng = np.random.default_rng(n + 20)
    M = np.stack([_conditioned(rng, 5, 1e6) for _ in range(n)])
    ratios = np.array([(np.sqrt(np.diag(m)) / np.diag(np.linalg.cholesky(m))).max() for m in M])
    for factor, expected in ((1.0 + 1e-9, True), (1.0 - 1e-9, False)):
        for w in range(n):
            _, ok = cholesky_solve(M, np.ones((n, 5)), ratio=ratios[w] * factor)
            assert bool(np.asarray(ok)[w]) is expected


def test_a_world_whose_solve_overflows_is_silent_as_its_one_world_solve():
    """World 1's right-hand side (1e306 against pivots of 1e-2) overflows in the
    substitution: N worlds give it LAPACK's non-finite answer without a RuntimeWarning
    (which the suite turns into an error), as its own one-world solve does, and world 0
    its own answer (the any-robot fuzz's batched path found the warning)."""
    M = np.tile(np.array([[1e-4, 0.5e-4, 0.0], [0.5e-4, 1e-4, 0.5e-4], [0.0, 0.5e-4, 1e-4]]), (2, 1, 1))
    b = np.array([[1.0, 2.0, 3.0], [1e306, -1e306, 1e306]])
    X, _ = cholesky_solve(M, b)
    alone = [cholesky_solve(M[w:w + 1], b[w:w + 1])[0][0] for w in range(2)]
    np.testing.assert_allclose(X[0], alone[0], rtol=ROUNDING, atol=ROUNDING * np.abs(alone[0]).max())
    assert not np.isfinite(X[1]).all() and not np.isfinite(alone[1]).all()


@pytest.mark.parametrize("n", [1, 3])
def test_cholesky_solve_of_no_rows_is_empty_and_solved(n):
    """A system of zero rows (a hierarchy level whose rows are all masked) is solved, not
    an untyped error of LAPACK's (as the hand-solved small systems once raised ValueError)."""
    X, ok = cholesky_solve(np.zeros((n, 0, 0)), np.zeros((n, 0)), ratio=1e6)
    assert X.shape == (n, 0) and ok.all()


@pytest.mark.parametrize("n", [1, 5])
def test_a_factor_solves_further_right_sides_as_a_fresh_solve(n):
    """A refinement's second right side, through the factor kept: each world's answer is a
    fresh solve's bit for bit (the same factor, the same substitution), in place or not,
    and a refused world's is zero."""
    M, b, _ = _systems(n, 4, seed=7)
    M[-1] = -np.eye(4)
    factor, ok = cholesky_factor(M, 1e6)
    first = cholesky_substitute(factor, b.copy(), ok)
    second_rhs = b[::-1].copy()
    in_place = second_rhs.copy()
    assert cholesky_substitute(factor, in_place, ok, in_place=True) is in_place
    again, _ = cholesky_solve(M, second_rhs, 1e6)
    np.testing.assert_array_equal(in_place, again)
    np.testing.assert_array_equal(first, cholesky_solve(M, b, 1e6)[0])
    assert not np.asarray(ok)[-1] and not in_place[-1].any()
